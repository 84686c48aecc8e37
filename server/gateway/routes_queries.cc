// The handlers of the queries on a mesh: distance, field, matrix, sample
// and snap, and the resolution of their points (SPEC strings, vertex ids,
// positions snapped in one Snap call). Apart from the mesh and graph routes
// (routes_meshes.cc) as the largest handlers, with the most to read.
#include <cstring>
#include <string>
#include <vector>

#include "absl/strings/str_format.h"
#include "core/query/matrix_files.h"
#include "core/query/result_files.h"
#include "server/api/convert.h"
#include "server/gateway/gateway_impl.h"
#include "server/gateway/json_answers.h"
#include "server/gateway/json_requests.h"

namespace geodesic::server {
// The gateway's helpers (gateway_call.h), unqualified as the handlers were
// written; this file is compiled alone, never in a unity batch.
using namespace gateway;  // NOLINT(build/namespaces)

// SPEC strings (or vertex ids) to points; "xyz:" positions are snapped
// through the Snap RPC, all of a request's in one call.
grpc::Status HttpGateway::Impl::Resolve(const Call& call, const std::string& mesh,
                                        const std::vector<json>& specs, const std::string& what,
                                        std::vector<v1::SurfacePoint>* out) {
  PointSpecs points;
  for (size_t i = 0; i < specs.size(); ++i) {
    const json& s = specs[i];
    if (s.is_number_unsigned()) {
      if (s.get<uint64_t>() > UINT32_MAX) {
        return grpc::Status(
            grpc::StatusCode::OUT_OF_RANGE,
            absl::StrFormat("%s %u: vertex id %s is out of range", what, i, Quote(s)));
      }
      points.AddVertex(s.get<uint32_t>());
      continue;
    }
    if (!s.is_string()) {
      return Invalid(
          absl::StrFormat("%s %u: expected a point spec string such as \"v:12\", "
                          "got %s",
                          what, i, Quote(s)));
    }
    if (absl::Status bad = points.Add(s.get<std::string>()); !bad.ok()) {
      return Invalid(absl::StrFormat("%s %u: %s", what, i, bad.message()));
    }
  }
  if (points.has_positions()) {
    v1::SnapResponse snapped;
    grpc::Status s = stub->Snap(call.Context(), points.SnapRequest(mesh), &snapped);
    if (!s.ok()) return s;
    if (absl::Status bad = points.Snapped(snapped); !bad.ok()) return ToGrpc(bad);
  }
  *out = std::move(points.points());
  return grpc::Status::OK;
}

grpc::Status HttpGateway::Impl::Specs(const Call& call, const std::string& mesh, const json& body,
                                      const char* key, const std::string& what,
                                      std::vector<v1::SurfacePoint>* out) {
  const json* array;
  if (grpc::Status s = ArrayField(body, key, &array); !s.ok()) return s;
  return Resolve(call, mesh, std::vector<json>(array->begin(), array->end()), what, out);
}

grpc::Status HttpGateway::Impl::Distance(const Call& call, const ApiRequest& r, json* out) {
  const std::string& mesh = r.mesh;
  const json& body = r.body;
  v1::DistanceRequest req;
  bool with_path;
  if (grpc::Status s = ForGraphOf(mesh, body, &req); !s.ok()) return s;
  if (grpc::Status s = BoolField(body, "path", &with_path); !s.ok()) return s;
  req.set_with_path(with_path);
  bool exact;
  if (grpc::Status s = BoolField(body, "exact", &exact); !s.ok()) return s;
  req.set_exact(exact);
  const json* pairs;
  if (grpc::Status s = ArrayField(body, "pairs", &pairs); !s.ok()) return s;
  std::vector<json> ends;
  for (size_t i = 0; i < pairs->size(); ++i) {
    const json& pair = (*pairs)[i];
    if (!pair.is_array() || pair.size() != 2) {
      return Invalid(
          absl::StrFormat("pair %u: expected [\"SPEC\", \"SPEC\"], got %s", i, Quote(pair)));
    }
    ends.push_back(pair[0]);
    ends.push_back(pair[1]);
  }
  std::vector<v1::SurfacePoint> points;
  if (grpc::Status s = Resolve(call, mesh, ends, "pair end", &points); !s.ok()) return s;
  for (size_t i = 0; i < points.size(); i += 2) {
    auto* pair = req.add_pairs();
    *pair->mutable_from() = points[i];
    *pair->mutable_to() = points[i + 1];
  }
  v1::DistanceResponse resp;
  grpc::Status s = stub->Distance(call.Context(), req, &resp);
  if (!s.ok()) return s;
  json distances = json::array(), paths = json::array(), path_lengths = json::array();
  for (const auto& r : resp.results()) {
    distances.push_back(r.reachable() ? JsonDistance(r.distance()) : json(nullptr));
    if (!with_path) continue;
    json path = json::array();
    for (const auto& p : r.path().points()) {
      path.push_back({p.xyz().x(), p.xyz().y(), p.xyz().z()});
    }
    paths.push_back(std::move(path));
    path_lengths.push_back(r.reachable() ? json(r.path().length()) : json(nullptr));
  }
  *out = {{"distances", std::move(distances)}, {"exact", exact}};
  AddEcho(resp.echo(), out);
  if (with_path) {
    (*out)["paths"] = std::move(paths);
    (*out)["path_lengths"] = std::move(path_lengths);  // each polyline's own length
  }
  return s;
}

grpc::Status HttpGateway::Impl::Field(const Call& call, const ApiRequest& r, json* out) {
  const std::string& mesh = r.mesh;
  const json& body = r.body;
  v1::DistanceFieldRequest req;
  bool nearest;
  if (grpc::Status s = ForGraphOf(mesh, body, &req); !s.ok()) return s;
  if (grpc::Status s = BoolField(body, "nearest_source", &nearest); !s.ok()) return s;
  req.set_nearest_source(nearest);
  if (auto it = body.find("max_distance"); it != body.end() && !it->is_null()) {
    if (!it->is_number()) return Invalid("\"max_distance\" must be a number");
    req.set_max_distance(it->get<double>());
  }
  if (auto it = body.find("method"); it != body.end() && !it->is_null()) {
    if (!it->is_string()) return Invalid("\"method\" must be \"lc\" or \"dijkstra\"");
    req.set_method(it->get<std::string>());
  }
  if (auto it = body.find("targets"); it != body.end() && !it->is_null()) {
    if (!it->is_array()) return Invalid("\"targets\" must be an array of vertex ids");
    for (size_t i = 0; i < it->size(); ++i) {
      const json& t = (*it)[i];
      if (!t.is_number_unsigned() || t.get<uint64_t>() > UINT32_MAX) {
        return Invalid(absl::StrFormat("target %u: %s is not a vertex id", i, Quote(t)));
      }
      req.add_targets(t.get<uint32_t>());
    }
  }
  std::vector<v1::SurfacePoint> sources;
  if (grpc::Status s = Specs(call, mesh, body, "sources", "source", &sources); !s.ok()) return s;
  for (auto& p : sources) *req.add_sources() = std::move(p);
  auto ctx = call.Context();
  auto reader = stub->DistanceField(ctx, req);
  std::vector<double> values;
  std::vector<uint32_t> nearest_source;
  v1::QueryEcho echo;
  v1::DistanceFieldChunk chunk;
  while (reader->Read(&chunk)) {
    if (chunk.has_echo()) echo = chunk.echo();
    if (!*r.hold && chunk.total() > 0) {
      const uint64_t numbers = uint64_t{chunk.total()} * (nearest ? 2 : 1);
      if (grpc::Status s =
              ReserveAnswer(r, numbers * kJsonNumberBytes,
                            absl::StrFormat("a field of %u values as JSON", chunk.total()));
          !s.ok()) {
        ctx->TryCancel();
        return s;
      }
    }
    if (values.size() < chunk.total()) values.resize(chunk.total());
    if (nearest && nearest_source.size() < chunk.total()) nearest_source.resize(chunk.total());
    if (chunk.offset() + chunk.values_size() > values.size()) {
      return grpc::Status(grpc::StatusCode::INTERNAL, "field chunk beyond the field's total");
    }
    for (int i = 0; i < chunk.values_size(); ++i) values[chunk.offset() + i] = chunk.values(i);
    for (int i = 0; i < chunk.nearest_source_size() && nearest; ++i) {
      nearest_source[chunk.offset() + i] = chunk.nearest_source(i);
    }
  }
  grpc::Status s = reader->Finish();
  if (!s.ok()) return s;
  json distances = json::array();
  for (double d : values) distances.push_back(JsonDistance(d));
  *out = {{"distances", std::move(distances)}};
  AddEcho(echo, out);
  if (nearest) (*out)["nearest_source"] = nearest_source;
  return s;
}

grpc::Status HttpGateway::Impl::Matrix(const Call& call, const ApiRequest& r, json* out) {
  const std::string& mesh = r.mesh;
  const json& body = r.body;
  v1::MatrixRequest req;
  if (grpc::Status s = ForGraphOf(mesh, body, &req); !s.ok()) return s;
  bool exact;
  if (grpc::Status s = BoolField(body, "exact", &exact); !s.ok()) return s;
  req.set_exact(exact);
  std::vector<v1::SurfacePoint> sources, targets;
  if (grpc::Status s = Specs(call, mesh, body, "sources", "source", &sources); !s.ok()) return s;
  if (grpc::Status s = Specs(call, mesh, body, "targets", "target", &targets); !s.ok()) return s;
  for (auto& p : sources) *req.add_sources() = std::move(p);
  for (auto& p : targets) *req.add_targets() = std::move(p);
  v1::MatrixDtype dtype;
  if (grpc::Status s = BodyDtype(body, &dtype); !s.ok()) return s;
  const bool npy = WantsNpy(r.http);
  // Packed bytes whenever a dtype is named or .npy is wanted: the .npy's
  // data is those bytes as they came.
  if (npy && dtype == v1::MATRIX_DTYPE_DEFAULT) dtype = v1::MATRIX_DTYPE_FLOAT64;
  req.set_dtype(dtype);
  const bool narrow = dtype == v1::MATRIX_DTYPE_FLOAT32;
  const size_t entry_bytes = narrow ? sizeof(float) : sizeof(double);
  // The answer arrives whole from the in-process channel, uncounted by the
  // service once sent, and is then copied into what goes out: both are in
  // memory at once, so both are counted, before the call, until the answer
  // is sent.
  const uint64_t asked = static_cast<uint64_t>(req.sources_size()) * req.targets_size();
  if (grpc::Status s =
          ReserveAnswer(r, asked * (entry_bytes + (npy ? entry_bytes : kJsonNumberBytes)),
                        absl::StrFormat("a matrix of %u x %u %s", req.sources_size(),
                                        req.targets_size(), npy ? "as .npy" : "as JSON"));
      !s.ok()) {
    return s;
  }
  v1::MatrixResponse resp;
  grpc::Status s = stub->Matrix(call.Context(), req, &resp);
  if (!s.ok()) return s;
  const uint64_t entries = static_cast<uint64_t>(resp.rows()) * resp.cols();
  const uint64_t got = dtype == v1::MATRIX_DTYPE_DEFAULT ? resp.distances_size()
                                                         : resp.packed().size() / entry_bytes;
  if (entries != asked || entries != got ||
      (dtype != v1::MATRIX_DTYPE_DEFAULT && resp.dtype() != dtype)) {
    return grpc::Status(grpc::StatusCode::INTERNAL, "matrix size does not match rows x cols");
  }
  if (npy) {
    HttpResponse& res = r.raw->emplace();
    const MatrixDtype descr = narrow ? MatrixDtype::kFloat32 : MatrixDtype::kFloat64;
    res.body = NpyPreamble(NpyDescr(descr), {resp.rows(), resp.cols()});
    res.body += resp.packed();
    res.content_type = "application/x-npy";
    return s;
  }
  auto entry = [&](uint64_t k) -> double {
    if (dtype == v1::MATRIX_DTYPE_DEFAULT) return resp.distances(static_cast<int>(k));
    if (narrow) {
      float value;
      std::memcpy(&value, resp.packed().data() + k * sizeof value, sizeof value);
      return value;
    }
    double value;
    std::memcpy(&value, resp.packed().data() + k * sizeof value, sizeof value);
    return value;
  };
  json rows = json::array();
  for (uint32_t r = 0; r < resp.rows(); ++r) {
    json row = json::array();
    for (uint32_t c = 0; c < resp.cols(); ++c) {
      row.push_back(JsonDistance(entry(uint64_t(r) * resp.cols() + c)));
    }
    rows.push_back(std::move(row));
  }
  *out = {{"distances", std::move(rows)}, {"exact", exact}};
  if (dtype != v1::MATRIX_DTYPE_DEFAULT) (*out)["dtype"] = narrow ? "float32" : "float64";
  AddEcho(resp.echo(), out);
  return s;
}

grpc::Status HttpGateway::Impl::Sample(const Call& call, const ApiRequest& r, json* out) {
  const std::string& mesh = r.mesh;
  const json& body = r.body;
  v1::SamplePointsRequest req;
  if (grpc::Status s = ForGraphOf(mesh, body, &req); !s.ok()) return s;
  auto count = body.find("count");
  if (count == body.end() || !count->is_number_unsigned() || count->get<uint64_t>() > UINT32_MAX) {
    return Invalid("\"count\" must be a number of points, at least 1");
  }
  req.set_count(count->get<uint32_t>());
  if (auto seed = body.find("seed"); seed != body.end() && !seed->is_null()) {
    if (!seed->is_number_unsigned()) return Invalid("\"seed\" must be a non-negative integer");
    req.set_seed(seed->get<uint64_t>());
  }
  v1::SamplePointsResponse resp;
  grpc::Status s = stub->SamplePoints(call.Context(), req, &resp);
  if (!s.ok()) return s;
  *out = {{"vertices", resp.vertices()}, {"covering_radius", JsonDistance(resp.covering_radius())}};
  AddEcho(resp.echo(), out);
  return s;
}

grpc::Status HttpGateway::Impl::Snap(const Call& call, const ApiRequest& r, json* out) {
  const std::string& mesh = r.mesh;
  const json& body = r.body;
  const json* positions;
  if (grpc::Status s = ArrayField(body, "positions", &positions); !s.ok()) return s;
  v1::SnapRequest req;
  req.set_mesh(mesh);
  for (size_t i = 0; i < positions->size(); ++i) {
    const json& p = (*positions)[i];
    if (!p.is_array() || p.size() != 3 || !p[0].is_number() || !p[1].is_number() ||
        !p[2].is_number()) {
      return Invalid(absl::StrFormat("position %u: expected [x, y, z], got %s", i, Quote(p)));
    }
    auto* q = req.add_positions();
    q->set_x(p[0].get<double>());
    q->set_y(p[1].get<double>());
    q->set_z(p[2].get<double>());
  }
  v1::SnapResponse resp;
  grpc::Status s = stub->Snap(call.Context(), req, &resp);
  if (!s.ok()) return s;
  json points = json::array();
  for (const auto& p : resp.points()) points.push_back(FormatPoint(p));
  json distances = json::array();
  for (double d : resp.distances()) distances.push_back(JsonDistance(d));
  *out = {{"points", std::move(points)}, {"distances", std::move(distances)}};
  return s;
}

}  // namespace geodesic::server
