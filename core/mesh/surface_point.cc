#include "core/mesh/surface_point.h"

#include <charconv>
#include <cmath>
#include <fstream>
#include <sstream>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"

namespace geodesic {
namespace {

bool ParseDouble(std::string_view text, double* out) {
  std::string copy(text);  // from_chars for double is not in libstdc++ 12's every mode
  char* end = nullptr;
  *out = std::strtod(copy.c_str(), &end);
  return !copy.empty() && end == copy.c_str() + copy.size();
}

bool ParseId(std::string_view text, uint32_t* out) {
  auto [ptr, ec] = std::from_chars(text.data(), text.data() + text.size(), *out);
  return ec == std::errc() && ptr == text.data() + text.size();
}

std::vector<std::string_view> Split(std::string_view text, char separator) {
  std::vector<std::string_view> parts;
  size_t start = 0;
  while (true) {
    size_t end = text.find(separator, start);
    parts.push_back(text.substr(start, end == std::string_view::npos ? end : end - start));
    if (end == std::string_view::npos) return parts;
    start = end + 1;
  }
}

absl::Status Bad(std::string_view text, std::string_view why) {
  return absl::InvalidArgumentError(absl::StrFormat(
      "bad surface point '%s': %s (expected v:ID, e:EDGE:T, f:FACE:B0,B1,B2 or xyz:X,Y,Z)", text,
      why));
}

}  // namespace

absl::StatusOr<SurfacePointSpec> ParseSurfacePointSpec(std::string_view text) {
  std::vector<std::string_view> parts = Split(text, ':');
  SurfacePointSpec spec;
  if (parts.size() == 2 && parts[0] == "v") {
    uint32_t id;
    if (!ParseId(parts[1], &id)) return Bad(text, "vertex id is not a non-negative integer");
    spec.point = SurfacePoint::Vertex(id);
    return spec;
  }
  if (parts.size() == 3 && parts[0] == "e") {
    uint32_t id;
    double t;
    if (!ParseId(parts[1], &id)) return Bad(text, "edge id is not a non-negative integer");
    if (!ParseDouble(parts[2], &t)) return Bad(text, "edge parameter is not a number");
    spec.point = SurfacePoint::Edge(id, t);
    return spec;
  }
  if (parts.size() == 3 && parts[0] == "f") {
    uint32_t id;
    if (!ParseId(parts[1], &id)) return Bad(text, "face id is not a non-negative integer");
    std::vector<std::string_view> b = Split(parts[2], ',');
    double w[3];
    if (b.size() != 3) return Bad(text, "a face point needs three barycentric coordinates");
    for (int k = 0; k < 3; ++k) {
      if (!ParseDouble(b[k], &w[k])) return Bad(text, "barycentric coordinate is not a number");
    }
    spec.point = SurfacePoint::Face(id, w[0], w[1], w[2]);
    return spec;
  }
  if (parts.size() == 2 && parts[0] == "xyz") {
    std::vector<std::string_view> c = Split(parts[1], ',');
    double x[3];
    if (c.size() != 3) return Bad(text, "a position needs three coordinates");
    for (int k = 0; k < 3; ++k) {
      if (!ParseDouble(c[k], &x[k]) || !std::isfinite(x[k])) {
        return Bad(text, "coordinate is not a finite number");
      }
    }
    spec.is_position = true;
    spec.position = {x[0], x[1], x[2]};
    return spec;
  }
  return Bad(text, "unknown form");
}

std::string FormatSurfacePoint(const SurfacePoint& p) {
  switch (p.kind) {
    case SurfacePoint::Kind::kVertex:
      return absl::StrFormat("v:%u", p.id);
    case SurfacePoint::Kind::kEdge:
      return absl::StrFormat("e:%u:%.17g", p.id, p.t);
    case SurfacePoint::Kind::kFace:
      return absl::StrFormat("f:%u:%.17g,%.17g,%.17g", p.id, p.bary[0], p.bary[1], p.bary[2]);
  }
  return "?";
}

absl::Status ValidateSurfacePoint(const Mesh& mesh, const SurfacePoint& p) {
  switch (p.kind) {
    case SurfacePoint::Kind::kVertex:
      if (p.id >= mesh.num_vertices()) {
        return absl::OutOfRangeError(absl::StrFormat(
            "vertex %u is out of range: the mesh has %u vertices", p.id, mesh.num_vertices()));
      }
      if (mesh.is_isolated(p.id)) {
        return absl::InvalidArgumentError(
            absl::StrFormat("vertex %u belongs to no face, so no geodesic reaches it", p.id));
      }
      return absl::OkStatus();
    case SurfacePoint::Kind::kEdge:
      if (p.id >= mesh.num_edges()) {
        return absl::OutOfRangeError(absl::StrFormat(
            "edge %u is out of range: the mesh has %u edges", p.id, mesh.num_edges()));
      }
      if (!(p.t >= 0 && p.t <= 1)) {
        return absl::InvalidArgumentError(
            absl::StrFormat("edge parameter %g is not in [0, 1]", p.t));
      }
      return absl::OkStatus();
    case SurfacePoint::Kind::kFace: {
      if (p.id >= mesh.num_faces()) {
        return absl::OutOfRangeError(absl::StrFormat(
            "face %u is out of range: the mesh has %u faces", p.id, mesh.num_faces()));
      }
      double sum = 0;
      for (double b : p.bary) {
        if (!(b >= 0) || !std::isfinite(b)) {
          return absl::InvalidArgumentError(absl::StrFormat(
              "barycentric coordinates (%g, %g, %g) must be finite and non-negative", p.bary[0],
              p.bary[1], p.bary[2]));
        }
        sum += b;
      }
      if (std::abs(sum - 1) > 1e-6) {
        return absl::InvalidArgumentError(
            absl::StrFormat("barycentric coordinates (%g, %g, %g) sum to %.9g, not 1", p.bary[0],
                            p.bary[1], p.bary[2], sum));
      }
      return absl::OkStatus();
    }
  }
  return absl::InvalidArgumentError("unknown surface point kind");
}

SurfacePoint CanonicalizeSurfacePoint(const Mesh& mesh, const SurfacePoint& p) {
  if (p.kind == SurfacePoint::Kind::kEdge) {
    const HalfedgeId h = mesh.edge_halfedge(p.id);
    if (p.t <= 0) return SurfacePoint::Vertex(mesh.tail(h));
    if (p.t >= 1) return SurfacePoint::Vertex(mesh.head(h));
    return p;
  }
  if (p.kind != SurfacePoint::Kind::kFace) return p;
  const double sum = p.bary[0] + p.bary[1] + p.bary[2];
  std::array<double, 3> b = {p.bary[0] / sum, p.bary[1] / sum, p.bary[2] / sum};
  int nonzero = 0, last = 0;
  for (int k = 0; k < 3; ++k) {
    if (b[k] > 0) {
      ++nonzero;
      last = k;
    }
  }
  if (nonzero == 1) return SurfacePoint::Vertex(mesh.face_vertex(p.id, last));
  if (nonzero == 2) {
    // The zero coordinate's corner is opposite the edge the point lies on:
    // half-edge from corner k+1 to corner k+2.
    for (int k = 0; k < 3; ++k) {
      if (b[k] > 0) continue;
      const HalfedgeId h = Mesh::halfedge(p.id, (k + 1) % 3);
      const double t = b[(k + 2) % 3];  // weight of head(h)
      const EdgeId e = mesh.edge(h);
      return SurfacePoint::Edge(e, mesh.edge_halfedge(e) == h ? t : 1 - t);
    }
  }
  return SurfacePoint::Face(p.id, b[0], b[1], b[2]);
}

Vec3 PositionOf(const Mesh& mesh, const SurfacePoint& p) {
  switch (p.kind) {
    case SurfacePoint::Kind::kVertex:
      return mesh.position(p.id);
    case SurfacePoint::Kind::kEdge:
      return mesh.point_on_halfedge(mesh.edge_halfedge(p.id), p.t);
    case SurfacePoint::Kind::kFace:
      return mesh.position(mesh.face_vertex(p.id, 0)) * p.bary[0] +
             mesh.position(mesh.face_vertex(p.id, 1)) * p.bary[1] +
             mesh.position(mesh.face_vertex(p.id, 2)) * p.bary[2];
  }
  return {};
}

absl::StatusOr<std::vector<SpecPair>> ReadSpecPairs(const std::string& path) {
  std::ifstream in(path);
  if (!in) return absl::NotFoundError(absl::StrFormat("cannot read %s", path));
  std::vector<SpecPair> pairs;
  std::string line;
  for (size_t number = 1; std::getline(in, line); ++number) {
    std::istringstream fields(line);
    std::vector<std::string> specs;
    for (std::string spec; fields >> spec;) specs.push_back(spec);
    if (specs.empty()) continue;
    if (specs.size() != 2) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s line %u: expected two points, found %u", path, number, specs.size()));
    }
    pairs.push_back({specs[0], specs[1]});
  }
  if (in.bad()) return absl::DataLossError(absl::StrFormat("error reading %s", path));
  return pairs;
}

}  // namespace geodesic
