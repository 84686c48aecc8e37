#include "server/geodesic_service.h"

#include <chrono>
#include <cstdio>
#include <optional>
#include <string_view>

#include "absl/cleanup/cleanup.h"
#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "absl/time/time.h"
#include "core/dgg_build.h"
#include "core/status.h"
#include "server/convert.h"
#include "server/log.h"

namespace geodesic::server {
namespace {

// The canonical name ("INVALID_ARGUMENT"): gRPC's codes are Abseil's.
std::string CodeName(grpc::StatusCode code) {
  return absl::StatusCodeToString(static_cast<absl::StatusCode>(code));
}

// A change of a mesh waited past the call's deadline for another change of
// the same mesh to finish.
absl::Status NameBusy(const std::string& mesh) {
  return absl::DeadlineExceededError(absl::StrFormat(
      "another change of mesh '%s' (a registration, unload or graph request) was still "
      "running when the deadline passed",
      mesh));
}

// Polled by long solves: the client went away or its deadline passed.
std::function<bool()> Cancelled(grpc::ServerContext* ctx) {
  return [ctx] { return ctx->IsCancelled() || ctx->deadline() < std::chrono::system_clock::now(); };
}

// Compares in time independent of where the strings differ, so that response
// times do not leak the token.
bool ConstantTimeEquals(std::string_view a, std::string_view b) {
  if (a.size() != b.size()) return false;
  unsigned char diff = 0;
  for (size_t i = 0; i < a.size(); ++i) diff |= static_cast<unsigned char>(a[i] ^ b[i]);
  return diff == 0;
}

bool HasBearerToken(const grpc::ServerContext& ctx, std::string_view token) {
  constexpr std::string_view kPrefix = "Bearer ";
  const auto& metadata = ctx.client_metadata();
  auto [begin, end] = metadata.equal_range("authorization");
  for (auto it = begin; it != end; ++it) {
    std::string_view value(it->second.data(), it->second.size());
    if (value.starts_with(kPrefix) && ConstantTimeEquals(value.substr(kPrefix.size()), token)) {
      return true;
    }
  }
  return false;
}

}  // namespace

absl::StatusOr<double> GeodesicService::Epsilon(double requested) const {
  const double eps = requested == 0 ? limits_.default_epsilon : requested;
  if (!(eps >= 1e-6 && eps <= 0.5)) {
    return absl::InvalidArgumentError(absl::StrFormat("epsilon %g is outside [1e-6, 0.5]", eps));
  }
  return eps;
}

absl::StatusOr<GraphKey> GeodesicService::Key(const std::string& mesh, double epsilon,
                                              bool pseudo) const {
  ASSIGN_OR_RETURN(const double eps, Epsilon(epsilon));
  GraphKey key{mesh, DggParams{}};
  key.params.epsilon = eps;
  key.params.pseudo_vertices = pseudo;
  key.params.exact_fans = limits_.exact_fans;
  return key;
}

absl::Status GeodesicService::Record(const RegisteredMesh& m, bool existed) {
  if (!catalog_) return absl::OkStatus();
  absl::Status s = catalog_->RecordMesh(
      {m.name, m.source, m.format, m.source_hash, m.fingerprint, m.repair_non_manifold});
  // Not recorded, not registered: a client told of an error must not find
  // the mesh answering here and gone after a restart.
  if (!s.ok() && !existed) meshes_->Remove(m.name).IgnoreError();
  return s;
}

absl::StatusOr<std::shared_ptr<const RegisteredMesh>> GeodesicService::FindMesh(
    const std::string& name) {
  auto m = meshes_->Get(name);
  if (m.ok() || !absl::IsNotFound(m.status()) || !catalog_) return m;
  // Registered on another replica sharing the graph directory, perhaps.
  RETURN_IF_ERROR(catalog_->ReconcileIfChanged());
  m = meshes_->Get(name);
  if (m.ok() || !absl::IsNotFound(m.status())) return m;
  if (std::optional<std::string> failure = catalog_->Failure(name)) {
    return absl::UnavailableError(absl::StrFormat(
        "mesh '%s' is in the catalog but could not be restored here (%s); the server tries "
        "again as it follows the catalog, or unload the mesh and register it again",
        name, *failure));
  }
  return m;
}

absl::StatusOr<std::shared_ptr<const GeodesicEngine>> GeodesicService::AcquireEngine(
    const GraphKey& key) {
  auto engine = graphs_->Acquire(key);
  if (engine.ok() || !catalog_ || graphs_->Get(key).ok()) return engine;
  // Requested on another replica, perhaps: follow the catalog, and give a
  // graph that only needs mapping from its file the moment that takes.
  RETURN_IF_ERROR(catalog_->ReconcileIfChanged());
  auto status = graphs_->Get(key);
  const absl::Time deadline = absl::Now() + absl::Seconds(2);
  while (status.ok() &&
         (status->state == GraphState::kQueued || status->state == GraphState::kLoading) &&
         absl::Now() < deadline) {
    status = graphs_->WaitForChange(key, status->version, deadline);
  }
  return graphs_->Acquire(key);
}

template <typename Body>
grpc::Status GeodesicService::Handle(const char* method, grpc::ServerContext* ctx,
                                     const std::string& mesh, bool is_query, Body body) {
  const auto start = std::chrono::steady_clock::now();
  grpc::Status status;
  if (!bearer_token_.empty() && !HasBearerToken(*ctx, bearer_token_)) {
    status = grpc::Status(grpc::StatusCode::UNAUTHENTICATED,
                          "missing or wrong bearer token: send metadata "
                          "'authorization: Bearer <token>'");
  } else if (is_query && inflight_.fetch_add(1) >= limits_.max_inflight) {
    inflight_.fetch_sub(1);
    status =
        grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED,
                     absl::StrFormat("server overloaded: %d queries running; retry with backoff",
                                     limits_.max_inflight));
  } else {
    if (is_query) metrics_->SetQueueDepth(inflight_.load());
    // Released however body() ends, so a throw cannot leak a query slot.
    absl::Cleanup release = [&] {
      if (is_query) inflight_.fetch_sub(1);
    };
    status = ToGrpc(body());
    // A solve stopped because the call's deadline passed reports that, not a
    // cancellation by the client.
    if (status.error_code() == grpc::StatusCode::CANCELLED && !ctx->IsCancelled() &&
        ctx->deadline() < std::chrono::system_clock::now()) {
      status = grpc::Status(grpc::StatusCode::DEADLINE_EXCEEDED,
                            "deadline exceeded: " + status.error_message());
    }
  }
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  metrics_->Record(method, CodeName(status.error_code()), seconds);
  if (limits_.log_requests) {
    if (status.ok()) {
      Log(LogLevel::kInfo, "request",
          {{"method", method},
           {"mesh", mesh},
           {"code", "OK"},
           {"ms", 1e3 * seconds},
           {"peer", ctx->peer()}});
    } else {
      Log(LogLevel::kInfo, "request",
          {{"method", method},
           {"mesh", mesh},
           {"code", CodeName(status.error_code())},
           {"ms", 1e3 * seconds},
           {"peer", ctx->peer()},
           {"error", status.error_message()}});
    }
  }
  return status;
}

namespace {

void FillMesh(const RegisteredMesh& m, v1::Mesh* out) {
  out->set_name(m.name);
  out->set_fingerprint(absl::StrFormat("%016x", m.fingerprint));
  out->set_source(m.source);
  out->set_restored(m.restored);
  out->set_repair_non_manifold(m.repair_non_manifold);
  for (const VertexCopy& c : m.vertex_copies) {
    auto* copy = out->add_vertex_copies();
    copy->set_original(c.original);
    copy->set_copy(c.copy);
  }
  auto* d = out->mutable_diagnostics();
  d->set_vertices(m.diagnostics.vertices);
  d->set_faces(m.diagnostics.faces);
  d->set_edges(m.diagnostics.edges);
  d->set_components(m.diagnostics.components);
  d->set_boundary_loops(m.diagnostics.boundary_loops);
  d->set_genus(m.diagnostics.genus);
  d->set_isolated_vertices(m.diagnostics.isolated_vertices);
  d->set_non_manifold_vertices(m.diagnostics.non_manifold_vertices);
  d->set_bbox_diagonal(m.diagnostics.bbox_diagonal);
  d->set_anisotropy_mean(m.diagnostics.anisotropy_mean);
  d->set_json(m.diagnostics.ToJson());
}

}  // namespace

grpc::Status GeodesicService::RegisterMesh(grpc::ServerContext* ctx,
                                           const v1::RegisterMeshRequest* req, v1::Mesh* resp) {
  return Handle("RegisterMesh", ctx, req->name(), false, [&]() -> absl::Status {
    NameLocks::Hold hold(names_, req->name(), absl::FromChrono(ctx->deadline()));
    if (!hold.held()) return NameBusy(req->name());
    const bool existed = meshes_->Get(req->name()).ok();
    auto m = meshes_->RegisterPath(req->name(), req->path(), req->repair_non_manifold());
    if (!m.ok()) return m.status();
    RETURN_IF_ERROR(Record(**m, existed));
    FillMesh(**m, resp);
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::UploadMesh(grpc::ServerContext* ctx,
                                         grpc::ServerReader<v1::UploadMeshRequest>* reader,
                                         v1::Mesh* resp) {
  std::string name, format, bytes;
  bool repair = false;
  return Handle("UploadMesh", ctx, name, false, [&]() -> absl::Status {
    v1::UploadMeshRequest chunk;
    while (reader->Read(&chunk)) {
      if (!chunk.name().empty()) name = chunk.name();
      if (!chunk.format().empty()) format = chunk.format();
      repair |= chunk.repair_non_manifold();
      if (bytes.size() + chunk.data().size() > limits_.max_upload_bytes) {
        return absl::ResourceExhaustedError(absl::StrFormat(
            "upload exceeds the limit of %u bytes (--max-upload-bytes)", limits_.max_upload_bytes));
      }
      bytes += chunk.data();
    }
    NameLocks::Hold hold(names_, name, absl::FromChrono(ctx->deadline()));
    if (!hold.held()) return NameBusy(name);
    const bool existed = meshes_->Get(name).ok();
    auto m = meshes_->RegisterBytes(name, format, bytes, repair);
    if (!m.ok()) return m.status();
    RETURN_IF_ERROR(Record(**m, existed));
    FillMesh(**m, resp);
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::ListMeshes(grpc::ServerContext* ctx, const v1::ListMeshesRequest*,
                                         v1::ListMeshesResponse* resp) {
  return Handle("ListMeshes", ctx, "", false, [&]() -> absl::Status {
    for (const auto& m : meshes_->List()) FillMesh(*m, resp->add_meshes());
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::GetMesh(grpc::ServerContext* ctx, const v1::GetMeshRequest* req,
                                      v1::Mesh* resp) {
  return Handle("GetMesh", ctx, req->name(), false, [&]() -> absl::Status {
    auto m = FindMesh(req->name());
    if (!m.ok()) return m.status();
    FillMesh(**m, resp);
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::UnloadMesh(grpc::ServerContext* ctx, const v1::UnloadMeshRequest* req,
                                         v1::UnloadMeshResponse*) {
  return Handle("UnloadMesh", ctx, req->name(), false, [&]() -> absl::Status {
    NameLocks::Hold hold(names_, req->name(), absl::FromChrono(ctx->deadline()));
    if (!hold.held()) return NameBusy(req->name());
    // The catalog first: once it no longer lists the mesh, no restart or
    // replica brings it back.
    bool catalogued = false;
    if (catalog_) {
      ASSIGN_OR_RETURN(catalogued, catalog_->ForgetMesh(req->name()));
    }
    absl::Status s = meshes_->Remove(req->name());
    graphs_->DropMesh(req->name());
    return catalogued ? absl::OkStatus() : s;
  });
}

grpc::Status GeodesicService::RequestGraph(grpc::ServerContext* ctx,
                                           const v1::RequestGraphRequest* req, v1::Graph* resp) {
  return Handle("RequestGraph", ctx, req->mesh(), false, [&]() -> absl::Status {
    NameLocks::Hold hold(names_, req->mesh(), absl::FromChrono(ctx->deadline()));
    if (!hold.held()) return NameBusy(req->mesh());
    ASSIGN_OR_RETURN(const GraphKey key, Key(req->mesh(), req->epsilon(), req->pseudo_vertices()));
    auto m = FindMesh(req->mesh());
    if (!m.ok()) return m.status();
    // Refused at once, before the catalog records it: a graph that cannot
    // fit the limits would otherwise hold a build worker for nothing.
    RETURN_IF_ERROR(graphs_->Admit(**m, key.params).status());
    if (catalog_) RETURN_IF_ERROR(catalog_->RecordGraph(key.mesh, key.params).status());
    ToProto(graphs_->Request(*m, key.params), resp);
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::GetGraph(grpc::ServerContext* ctx, const v1::GetGraphRequest* req,
                                       v1::Graph* resp) {
  return Handle("GetGraph", ctx, req->mesh(), false, [&]() -> absl::Status {
    ASSIGN_OR_RETURN(const GraphKey key, Key(req->mesh(), req->epsilon(), req->pseudo_vertices()));
    auto g = graphs_->Get(key);
    if (!g.ok()) return g.status();
    ToProto(*g, resp);
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::WatchGraph(grpc::ServerContext* ctx, const v1::GetGraphRequest* req,
                                         grpc::ServerWriter<v1::Graph>* writer) {
  return Handle("WatchGraph", ctx, req->mesh(), false, [&]() -> absl::Status {
    ASSIGN_OR_RETURN(const GraphKey key, Key(req->mesh(), req->epsilon(), req->pseudo_vertices()));
    auto g = graphs_->Get(key);
    while (g.ok()) {
      v1::Graph out;
      ToProto(*g, &out);
      if (!writer->Write(out)) return absl::CancelledError("client went away");
      if (g->state != GraphState::kQueued && g->state != GraphState::kBuilding &&
          g->state != GraphState::kLoading && g->state != GraphState::kPersisting) {
        return absl::OkStatus();
      }
      if (Cancelled(ctx)()) return absl::CancelledError("watch cancelled");
      g = graphs_->WaitForChange(key, g->version, absl::Now() + absl::Seconds(1));
    }
    return g.status();
  });
}

grpc::Status GeodesicService::CancelGraph(grpc::ServerContext* ctx,
                                          const v1::CancelGraphRequest* req, v1::Graph* resp) {
  return Handle("CancelGraph", ctx, req->mesh(), false, [&]() -> absl::Status {
    NameLocks::Hold hold(names_, req->mesh(), absl::FromChrono(ctx->deadline()));
    if (!hold.held()) return NameBusy(req->mesh());
    ASSIGN_OR_RETURN(const GraphKey key, Key(req->mesh(), req->epsilon(), req->pseudo_vertices()));
    auto g = graphs_->Cancel(key);
    // A ready graph has no operation to cancel: it stays catalogued and
    // served. Anything else is forgotten, also when only another replica
    // requested it.
    const bool ready =
        g.ok() && (g->state == GraphState::kReady || g->state == GraphState::kEvicted);
    if (catalog_ && !ready) RETURN_IF_ERROR(catalog_->ForgetGraph(key.mesh, key.params).status());
    if (!g.ok()) return g.status();
    ToProto(*g, resp);
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::ListGraphs(grpc::ServerContext* ctx, const v1::ListGraphsRequest*,
                                         v1::ListGraphsResponse* resp) {
  return Handle("ListGraphs", ctx, "", false, [&]() -> absl::Status {
    for (const auto& g : graphs_->List()) ToProto(g, resp->add_graphs());
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::DistanceField(grpc::ServerContext* ctx,
                                            const v1::DistanceFieldRequest* req,
                                            grpc::ServerWriter<v1::DistanceFieldChunk>* writer) {
  return Handle("DistanceField", ctx, req->mesh(), true, [&]() -> absl::Status {
    if (req->sources_size() == 0) return absl::InvalidArgumentError("a field needs a source");
    if (req->sources_size() > limits_.max_sources) {
      return absl::ResourceExhaustedError(absl::StrFormat(
          "%d sources exceed the limit of %d per field", req->sources_size(), limits_.max_sources));
    }
    ASSIGN_OR_RETURN(const GraphKey key, Key(req->mesh(), req->epsilon(), req->pseudo_vertices()));
    const double eps = key.params.epsilon;
    if (auto known = FindMesh(req->mesh()); !known.ok()) return known.status();
    auto engine = AcquireEngine(key);
    if (!engine.ok()) return engine.status();
    const Mesh& mesh = (*engine)->mesh();
    std::vector<SurfacePoint> sources;
    for (int i = 0; i < req->sources_size(); ++i) {
      auto p = FromProto(req->sources(i), mesh, absl::StrFormat("source %d", i));
      if (!p.ok()) return p.status();
      sources.push_back(*p);
    }
    FieldOptions options;
    options.method =
        req->method() == "dijkstra" ? FieldMethod::kDijkstra : FieldMethod::kLabelCorrecting;
    if (!req->method().empty() && req->method() != "lc" && req->method() != "dijkstra") {
      return absl::InvalidArgumentError("method must be \"lc\" or \"dijkstra\"");
    }
    if (req->max_distance() > 0) options.max_distance = req->max_distance();
    options.nearest_source = req->nearest_source();
    options.cancelled = Cancelled(ctx);
    for (uint32_t t : req->targets()) {
      if (t >= mesh.num_vertices()) {
        return absl::OutOfRangeError(absl::StrFormat(
            "target vertex %u is out of range: the mesh has %u vertices", t, mesh.num_vertices()));
      }
    }
    auto field = (*engine)->Field(sources, options);
    if (!field.ok()) return field.status();
    std::vector<uint32_t> order(req->targets().begin(), req->targets().end());
    const size_t total = order.empty() ? field->distance.size() : order.size();
    for (size_t offset = 0; offset < total || offset == 0; offset += limits_.field_chunk) {
      v1::DistanceFieldChunk chunk;
      if (offset == 0) {
        chunk.mutable_echo()->set_mesh(req->mesh());
        chunk.mutable_echo()->set_epsilon(eps);
        chunk.mutable_echo()->set_method(options.method == FieldMethod::kDijkstra ? "dijkstra"
                                                                                  : "lc");
        chunk.mutable_echo()->set_pseudo_vertices(key.params.pseudo_vertices);
      }
      chunk.set_offset(offset);
      chunk.set_total(total);
      const size_t end = std::min(total, offset + limits_.field_chunk);
      for (size_t i = offset; i < end; ++i) {
        const uint32_t v = order.empty() ? i : order[i];
        if (req->float32()) {
          chunk.add_values_f32(static_cast<float>(field->distance[v]));
        } else {
          chunk.add_values(field->distance[v]);
        }
        if (req->nearest_source()) chunk.add_nearest_source(field->nearest_source[v]);
      }
      if (!writer->Write(chunk)) return absl::CancelledError("client went away");
      if (total == 0) break;
    }
    return absl::OkStatus();
  });
}

namespace {

void FillPath(const GeodesicPath& path, v1::Path* out) {
  out->set_length(path.length);
  for (const PathPoint& p : path.points) {
    auto* q = out->add_points();
    *q->mutable_point() = ToProto(p.point);
    q->mutable_xyz()->set_x(p.xyz.x);
    q->mutable_xyz()->set_y(p.xyz.y);
    q->mutable_xyz()->set_z(p.xyz.z);
  }
}

}  // namespace

grpc::Status GeodesicService::Distance(grpc::ServerContext* ctx, const v1::DistanceRequest* req,
                                       v1::DistanceResponse* resp) {
  return Handle("Distance", ctx, req->mesh(), true, [&]() -> absl::Status {
    if (req->pairs_size() > limits_.max_pairs) {
      return absl::ResourceExhaustedError(absl::StrFormat(
          "%d pairs exceed the limit of %d per call", req->pairs_size(), limits_.max_pairs));
    }
    ASSIGN_OR_RETURN(const GraphKey key, Key(req->mesh(), req->epsilon(), req->pseudo_vertices()));
    if (auto known = FindMesh(req->mesh()); !known.ok()) return known.status();
    auto engine = AcquireEngine(key);
    if (!engine.ok()) return engine.status();
    const Mesh& mesh = (*engine)->mesh();
    resp->mutable_echo()->set_mesh(req->mesh());
    resp->mutable_echo()->set_epsilon(key.params.epsilon);
    resp->mutable_echo()->set_pseudo_vertices(key.params.pseudo_vertices);
    resp->mutable_echo()->set_method("bidirectional-astar");
    PairOptions options;
    options.want_path = req->with_path();
    options.cancelled = Cancelled(ctx);
    for (int i = 0; i < req->pairs_size(); ++i) {
      auto a = FromProto(req->pairs(i).from(), mesh, absl::StrFormat("pair %d, from", i));
      if (!a.ok()) return a.status();
      auto b = FromProto(req->pairs(i).to(), mesh, absl::StrFormat("pair %d, to", i));
      if (!b.ok()) return b.status();
      auto r = (*engine)->Distance(*a, *b, options);
      if (!r.ok()) return r.status();
      auto* out = resp->add_results();
      out->set_distance(r->distance);
      out->set_reachable(r->distance < kInfinity);
      if (r->path) FillPath(*r->path, out->mutable_path());
    }
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::Matrix(grpc::ServerContext* ctx, const v1::MatrixRequest* req,
                                     v1::MatrixResponse* resp) {
  return Handle("Matrix", ctx, req->mesh(), true, [&]() -> absl::Status {
    if (req->sources_size() > limits_.max_sources || req->targets_size() > limits_.max_pairs) {
      return absl::ResourceExhaustedError(absl::StrFormat(
          "matrix of %d x %d exceeds the limits (%d sources, %d targets)", req->sources_size(),
          req->targets_size(), limits_.max_sources, limits_.max_pairs));
    }
    ASSIGN_OR_RETURN(const GraphKey key, Key(req->mesh(), req->epsilon(), req->pseudo_vertices()));
    if (auto known = FindMesh(req->mesh()); !known.ok()) return known.status();
    auto engine = AcquireEngine(key);
    if (!engine.ok()) return engine.status();
    const Mesh& mesh = (*engine)->mesh();
    std::vector<SurfacePoint> sources, targets;
    for (int i = 0; i < req->sources_size(); ++i) {
      auto p = FromProto(req->sources(i), mesh, absl::StrFormat("source %d", i));
      if (!p.ok()) return p.status();
      sources.push_back(*p);
    }
    for (int i = 0; i < req->targets_size(); ++i) {
      auto p = FromProto(req->targets(i), mesh, absl::StrFormat("target %d", i));
      if (!p.ok()) return p.status();
      targets.push_back(*p);
    }
    auto m = (*engine)->Matrix(sources, targets, Cancelled(ctx));
    if (!m.ok()) return m.status();
    resp->mutable_echo()->set_mesh(req->mesh());
    resp->mutable_echo()->set_epsilon(key.params.epsilon);
    resp->mutable_echo()->set_pseudo_vertices(key.params.pseudo_vertices);
    // One fan-restricted field per row (the "lc" solver), joined at the
    // targets as Distance joins its points.
    resp->mutable_echo()->set_method("lc");
    resp->set_rows(sources.size());
    resp->set_cols(targets.size());
    for (double d : *m) resp->add_distances(d);
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::Snap(grpc::ServerContext* ctx, const v1::SnapRequest* req,
                                   v1::SnapResponse* resp) {
  return Handle("Snap", ctx, req->mesh(), true, [&]() -> absl::Status {
    if (req->positions_size() > limits_.max_pairs) {
      return absl::ResourceExhaustedError(
          absl::StrFormat("%d positions exceed the limit of %d per call", req->positions_size(),
                          limits_.max_pairs));
    }
    auto m = FindMesh(req->mesh());
    if (!m.ok()) return m.status();
    for (const auto& p : req->positions()) {
      const Vec3 position{p.x(), p.y(), p.z()};
      auto s = (*m)->locator->Snap(position);
      if (!s.ok()) return s.status();
      *resp->add_points() = ToProto(*s);
      resp->add_distances(geodesic::Distance(position, PositionOf(*(*m)->mesh, *s)));
    }
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::SamplePoints(grpc::ServerContext* ctx,
                                           const v1::SamplePointsRequest* req,
                                           v1::SamplePointsResponse* resp) {
  return Handle("SamplePoints", ctx, req->mesh(), true, [&]() -> absl::Status {
    // Each point costs a field: a count is bounded like a field's sources.
    if (req->count() > static_cast<uint32_t>(limits_.max_pairs)) {
      return absl::ResourceExhaustedError(absl::StrFormat(
          "%u points exceed the limit of %d per call", req->count(), limits_.max_pairs));
    }
    ASSIGN_OR_RETURN(const GraphKey key, Key(req->mesh(), req->epsilon(), req->pseudo_vertices()));
    if (auto known = FindMesh(req->mesh()); !known.ok()) return known.status();
    ASSIGN_OR_RETURN(std::shared_ptr<const GeodesicEngine> engine, AcquireEngine(key));
    SampleOptions options;
    options.seed = req->seed();
    options.cancelled = Cancelled(ctx);
    ASSIGN_OR_RETURN(SampleResult sample, engine->SamplePoints(req->count(), options));
    resp->mutable_echo()->set_mesh(req->mesh());
    resp->mutable_echo()->set_epsilon(key.params.epsilon);
    resp->mutable_echo()->set_pseudo_vertices(key.params.pseudo_vertices);
    resp->mutable_echo()->set_method("farthest-point");
    for (VertexId v : sample.vertices) resp->add_vertices(v);
    resp->set_covering_radius(sample.covering_radius);
    return absl::OkStatus();
  });
}

}  // namespace geodesic::server
