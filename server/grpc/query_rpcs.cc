// The query RPCs that answer per point or pair: fields, distances and
// paths, snapping and sampling.
#include <algorithm>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <optional>
#include <string_view>
#include <thread>

#include "absl/cleanup/cleanup.h"
#include "absl/functional/function_ref.h"
#include "absl/status/status.h"
#include "absl/strings/cord.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/time/time.h"
#include "core/base/status.h"
#include "core/dgg/dgg_build.h"
#include "server/api/convert.h"
#include "server/base/echo.h"
#include "server/base/log.h"
#include "server/grpc/geodesic_service.h"
#include "server/grpc/rpc_support.h"
#include "server/limits/client_key.h"
#include "server/meshes/upload.h"

namespace geodesic::server {

grpc::Status GeodesicService::DistanceField(grpc::ServerContext* ctx,
                                            const v1::DistanceFieldRequest* req,
                                            grpc::ServerWriter<v1::DistanceFieldChunk>* writer) {
  const v1::GraphSelector graph = SelectorOf(*req);
  // A query, admitted in the body: the stream gives its place back once the
  // field is computed.
  return Handle("DistanceField", ctx, graph.mesh(), [&](const Call& call) -> absl::Status {
    ASSIGN_OR_RETURN(Admission::Ticket admitted, AdmitQuery(call));
    if (req->sources_size() == 0) return absl::InvalidArgumentError("a field needs a source");
    if (req->sources_size() > limits_.max_sources) {
      return OverLimits(absl::StrFormat("%d sources exceed the limit of %d per field",
                                        req->sources_size(), limits_.max_sources),
                        {{"max-sources", limits_.max_sources}});
    }
    ASSIGN_OR_RETURN(const GraphKey key, Key(graph));
    auto engine = AcquireEngine(key, call);
    if (!engine.ok()) return engine.status();
    const Mesh& mesh = (*engine)->mesh();
    ASSIGN_OR_RETURN(const std::vector<SurfacePoint> sources,
                     PointsFromProto(req->sources(), mesh, "source"));
    FieldOptions options;
    options.method =
        req->method() == "dijkstra" ? FieldMethod::kDijkstra : FieldMethod::kLabelCorrecting;
    if (!req->method().empty() && req->method() != "lc" && req->method() != "dijkstra") {
      return absl::InvalidArgumentError("method must be \"lc\" or \"dijkstra\"");
    }
    if (!(req->max_distance() >= 0)) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "max_distance %g is not a distance >= 0 (0: no limit)", req->max_distance()));
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
    // The field is streamed: its answer's peak is one chunk beside the
    // solver's arrays, which the scratch counts.
    const uint64_t chunk_bytes = uint64_t(limits_.field_chunk) *
                                     ((req->float32() ? 5 : 9) + (req->nearest_source() ? 6 : 0)) +
                                 kAnswerOverhead;
    ASSIGN_OR_RETURN(Admission::Ticket run,
                     StartQuery(call, 2 * chunk_bytes + uint64_t(req->targets_size()) * 4,
                                FieldScratchBytes(**engine)));
    auto field = (*engine)->Field(sources, options);
    if (!field.ok()) return field.status();
    // What is left is sending: the places go to other queries while the
    // client takes its chunks, however slowly; the answer's bytes stay
    // counted.
    const Admission::Ticket sending = admission_.KeepAnswer(std::move(run));
    admitted.Release();
    StreamWatchdog::Watch watch = WatchStream("DistanceField", ctx);
    std::vector<uint32_t> order(req->targets().begin(), req->targets().end());
    const size_t total = order.empty() ? field->distance.size() : order.size();
    for (size_t offset = 0; offset < total || offset == 0; offset += limits_.field_chunk) {
      v1::DistanceFieldChunk chunk;
      if (offset == 0) {
        FillEcho(Built(key, **engine), options.method == FieldMethod::kDijkstra ? "dijkstra" : "lc",
                 chunk.mutable_echo());
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
      RETURN_IF_ERROR(Send(watch, writer, chunk));
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
  const v1::GraphSelector graph = SelectorOf(*req);
  return Handle("Distance", ctx, graph.mesh(), [&](const Call& call) -> absl::Status {
    if (req->pairs_size() > limits_.max_pairs) {
      return OverLimits(absl::StrFormat("%d pairs exceed the limit of %d per call",
                                        req->pairs_size(), limits_.max_pairs),
                        {{"max-pairs", limits_.max_pairs}});
    }
    if (req->exact() && req->pairs_size() > limits_.max_exact_pairs) {
      return OverLimits(absl::StrFormat("%d exact pairs exceed the limit of %d exact pairs per "
                                        "call (--max-exact-pairs): split the batch",
                                        req->pairs_size(), limits_.max_exact_pairs),
                        {{"max-exact-pairs", limits_.max_exact_pairs}});
    }
    const uint64_t pairs = req->pairs_size();
    RETURN_IF_ERROR(CheckAnswerSize(absl::StrFormat("%u pairs", pairs),
                                    pairs * kPairResultBytes + kAnswerOverhead));
    ASSIGN_OR_RETURN(const GraphKey key, Key(graph));
    auto engine = AcquireEngine(key, call);
    if (!engine.ok()) return engine.status();
    if (req->exact()) graphs_->WantExactLandmarks(key);
    const Mesh& mesh = (*engine)->mesh();
    // The reply and, once the handler returns, its serialized copy.
    const uint64_t per_pair =
        kPairResultBytes + (req->with_path() ? kPathPointsReserved * kPathPointBytes : 0);
    const uint64_t answer =
        std::min<uint64_t>(pairs * per_pair + kAnswerOverhead, limits_.max_message_bytes);
    std::vector<SurfacePoint> from, to;
    for (int i = 0; i < req->pairs_size(); ++i) {
      ASSIGN_OR_RETURN(from.emplace_back(),
                       FromProto(req->pairs(i).from(), mesh, absl::StrFormat("pair %d, from", i)));
      ASSIGN_OR_RETURN(to.emplace_back(),
                       FromProto(req->pairs(i).to(), mesh, absl::StrFormat("pair %d, to", i)));
    }
    // A request's pairs are spread over the cores, each on its own scratch.
    const uint64_t lanes = std::clamp<uint64_t>(pairs, 1, std::thread::hardware_concurrency());
    // An exact pair may hold up to max_exact_bytes of windows on each lane.
    const uint64_t exact_bytes = req->exact() ? limits_.max_exact_bytes : 0;
    const uint64_t scratch = lanes * (PairScratchBytes(**engine) + exact_bytes);
    ASSIGN_OR_RETURN(Admission::Ticket run, StartQuery(call, 2 * answer, scratch));
    absl::Time slice_start = absl::Now();
    uint64_t answer_bytes = kAnswerOverhead;
    FillEcho(Built(key, **engine), req->exact() ? "exact" : "bidirectional-astar",
             resp->mutable_echo());
    PairOptions options;
    options.want_path = req->with_path();
    options.exact = req->exact();
    options.exact_max_bytes = limits_.max_exact_bytes;
    options.cancelled = Cancelled(ctx);
    // The pairs go in blocks, between which a call that has used its slice
    // gives its slot to a waiting client's query: an exact pair per lane at
    // a time, graph pairs a few dozen per lane (a batch of --max-pairs takes
    // seconds). With paths, which are as long as they are, the answer is
    // refused as soon as it cannot be sent, not after them all.
    const size_t block = req->exact() ? lanes : req->with_path() ? 8 * lanes : 64 * lanes;
    for (size_t begin = 0; begin < from.size(); begin += block) {
      if (begin > 0) RETURN_IF_ERROR(NextSlice(call, run, slice_start, scratch));
      const size_t count = std::min(block, from.size() - begin);
      ASSIGN_OR_RETURN(
          std::vector<PairResult> results,
          (*engine)->Distances(absl::MakeConstSpan(from).subspan(begin, count),
                               absl::MakeConstSpan(to).subspan(begin, count), options));
      for (size_t k = 0; k < results.size(); ++k) {
        const PairResult& r = results[k];
        auto* out = resp->add_results();
        out->set_distance(r.distance);
        out->set_reachable(r.distance < kInfinity);
        out->set_exact(r.exact);
        if (!r.path) continue;
        FillPath(*r.path, out->mutable_path());
        answer_bytes += out->ByteSizeLong() + 4;
        if (answer_bytes > limits_.max_message_bytes) {
          return OverLimits(absl::StrFormat("the answer with paths grew larger than max message "
                                            "size: %u bytes at pair %u of %d, over the cap of %u "
                                            "bytes; split the batch",
                                            answer_bytes, begin + k + 1, req->pairs_size(),
                                            limits_.max_message_bytes),
                            {{"max-message-bytes", limits_.max_message_bytes}});
        }
      }
    }
    HoldUntilSent(ctx, std::move(run));
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::Snap(grpc::ServerContext* ctx, const v1::SnapRequest* req,
                                   v1::SnapResponse* resp) {
  return Handle("Snap", ctx, req->mesh(), [&](const Call& call) -> absl::Status {
    if (req->positions_size() > limits_.max_pairs) {
      return OverLimits(absl::StrFormat("%d positions exceed the limit of %d per call",
                                        req->positions_size(), limits_.max_pairs),
                        {{"max-pairs", limits_.max_pairs}});
    }
    auto m = FindMesh(req->mesh());
    if (!m.ok()) return m.status();
    constexpr uint64_t kSnapBytes = 48;  // a point and its distance
    ASSIGN_OR_RETURN(
        Admission::Ticket run,
        StartQuery(call, 2 * (req->positions_size() * kSnapBytes + kAnswerOverhead), 0));
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
  const v1::GraphSelector graph = SelectorOf(*req);
  return Handle("SamplePoints", ctx, graph.mesh(), [&](const Call& call) -> absl::Status {
    // Each point costs a field.
    if (req->count() > static_cast<uint32_t>(limits_.max_samples)) {
      return OverLimits(absl::StrFormat("%u points exceed the limit of %d per call (--max-samples)",
                                        req->count(), limits_.max_samples),
                        {{"max-samples", limits_.max_samples}});
    }
    ASSIGN_OR_RETURN(const GraphKey key, Key(graph));
    ASSIGN_OR_RETURN(std::shared_ptr<const GeodesicEngine> engine, AcquireEngine(key, call));
    // A field's arrays and each vertex's distance to the samples so far.
    const uint64_t answer = 2 * (uint64_t(req->count()) * 6 + kAnswerOverhead);
    const uint64_t scratch =
        FieldScratchBytes(*engine) + uint64_t(engine->mesh().num_vertices()) * sizeof(double);
    ASSIGN_OR_RETURN(Admission::Ticket run, StartQuery(call, answer, scratch));
    absl::Time slice_start = absl::Now();
    SampleOptions options;
    options.seed = req->seed();
    options.cancelled = Cancelled(ctx);
    options.between_points = [&] { return NextSlice(call, run, slice_start, scratch); };
    ASSIGN_OR_RETURN(SampleResult sample, engine->SamplePoints(req->count(), options));
    FillEcho(Built(key, *engine), "farthest-point", resp->mutable_echo());
    for (VertexId v : sample.vertices) resp->add_vertices(v);
    resp->set_covering_radius(sample.covering_radius);
    return absl::OkStatus();
  });
}

}  // namespace geodesic::server
