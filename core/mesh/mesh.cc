#include "core/mesh/mesh.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <numbers>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "core/base/status.h"
#include "xxhash.h"

namespace geodesic {
namespace {

// Angle at `a` of triangle (a, b, c) from its side lengths; the law of cosines
// clamped so that slivers and zero-area faces give 0 or pi, never NaN.
double AngleFromLengths(double ab, double ac, double bc) {
  if (ab <= 0 || ac <= 0) return 0;
  double c = (ab * ab + ac * ac - bc * bc) / (2 * ab * ac);
  return std::acos(std::clamp(c, -1.0, 1.0));
}

}  // namespace

void SortEdgeUses(EdgeUses& uses, size_t num_vertices) {
  // Least significant digit first, each pass stable: the index order among
  // equal keys survives. Keys are repacked as min << bits | max first.
  const int bits = std::max(1, static_cast<int>(std::bit_width(num_vertices)));
  for (auto& u : uses) u.first = (u.first >> 32) << bits | (u.first & 0xffffffffu);
  constexpr int kDigit = 11;
  std::vector<std::pair<uint64_t, uint32_t>> buffer(uses.size());
  for (int shift = 0; shift < 2 * bits; shift += kDigit) {
    std::vector<size_t> start((1 << kDigit) + 1, 0);
    for (const auto& u : uses) ++start[(u.first >> shift & ((1 << kDigit) - 1)) + 1];
    for (size_t i = 1; i < start.size(); ++i) start[i] += start[i - 1];
    for (const auto& u : uses) buffer[start[u.first >> shift & ((1 << kDigit) - 1)]++] = u;
    uses.swap(buffer);
  }
  const uint64_t low = (uint64_t{1} << bits) - 1;
  for (auto& u : uses) u.first = (u.first >> bits) << 32 | (u.first & low);
}

namespace {

// Refuses what no half-edge structure can hold: ids beyond 32 bits,
// non-finite coordinates, corners out of range and faces repeating a vertex.
absl::Status CheckSoup(const TriangleSoup& soup, std::string_view source) {
  const size_t nv = soup.positions.size();
  const size_t nf = soup.triangles.size();
  if (nv >= kNone || 3 * nf >= kNone) {
    return absl::ResourceExhaustedError(
        absl::StrFormat("%s: %u vertices and %u faces exceed the 32-bit id range", source, nv, nf));
  }
  for (size_t v = 0; v < nv; ++v) {
    const Vec3& p = soup.positions[v];
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s: vertex %u has a non-finite coordinate (%g, %g, %g)", source, v, p.x, p.y, p.z));
    }
  }
  for (size_t f = 0; f < nf; ++f) {
    const auto& t = soup.triangles[f];
    for (int k = 0; k < 3; ++k) {
      if (t[k] >= nv) {
        return absl::InvalidArgumentError(
            absl::StrFormat("%s: face %u refers to vertex %u, but there are only %u vertices",
                            source, f, t[k], nv));
      }
    }
    if (t[0] == t[1] || t[1] == t[2] || t[0] == t[2]) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s: face %u repeats a vertex (%u %u %u)", source, f, t[0], t[1], t[2]));
    }
  }
  return absl::OkStatus();
}

// The first edge shorter than kMinEdgeLength but not zero (zero-length
// edges are degenerate faces, which the engines skip): false if none. Only
// an edge whose largest coordinate difference is below the bound can be,
// and only those pay for hypot, which neither underflows nor overflows as
// a squared length would.
bool FindTooShortEdge(const TriangleSoup& soup, size_t* face, int* corner, double* length) {
  for (size_t f = 0; f < soup.triangles.size(); ++f) {
    for (int k = 0; k < 3; ++k) {
      const Vec3 d =
          soup.positions[soup.triangles[f][(k + 1) % 3]] - soup.positions[soup.triangles[f][k]];
      if (std::max({std::abs(d.x), std::abs(d.y), std::abs(d.z)}) >= kMinEdgeLength) continue;
      const double l = std::hypot(d.x, d.y, d.z);
      if (l > 0 && l < kMinEdgeLength) {
        *face = f;
        *corner = k;
        *length = l;
        return true;
      }
    }
  }
  return false;
}

// Refuses a mesh whose lengths the engines cannot represent accurately (see
// kMinEdgeLength in mesh.h), naming the measure, its value and the range.
absl::Status CheckScale(const TriangleSoup& soup, std::string_view source) {
  if (soup.positions.empty()) return absl::OkStatus();
  Vec3 lo = soup.positions[0], hi = lo;
  for (const Vec3& p : soup.positions) {
    lo = {std::min(lo.x, p.x), std::min(lo.y, p.y), std::min(lo.z, p.z)};
    hi = {std::max(hi.x, p.x), std::max(hi.y, p.y), std::max(hi.z, p.z)};
  }
  const double diagonal = std::hypot(hi.x - lo.x, hi.y - lo.y, hi.z - lo.z);
  const std::string range = absl::StrFormat(
      "usable range: edges of at least %g and a bounding-box diagonal of at most "
      "%g; rescale the mesh's units",
      kMinEdgeLength, kMaxMeshDiagonal);
  if (diagonal > kMaxMeshDiagonal) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: bounding-box diagonal %g is too large to measure accurately (%s)",
                        source, diagonal, range));
  }
  size_t face = 0;
  int corner = 0;
  double length = 0;
  if (FindTooShortEdge(soup, &face, &corner, &length)) {
    const auto& t = soup.triangles[face];
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: edge %u-%u of face %u is %g long, too short to measure accurately (%s)", source,
        t[corner], t[(corner + 1) % 3], face, length, range));
  }
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<Mesh> Mesh::Build(TriangleSoup soup, std::string_view source) {
  RETURN_IF_ERROR(CheckSoup(soup, source));
  RETURN_IF_ERROR(CheckScale(soup, source));
  Mesh m;
  const size_t nf = soup.triangles.size();
  m.a_.corners.resize(3 * nf);
  for (size_t f = 0; f < nf; ++f) {
    for (int k = 0; k < 3; ++k) m.a_.corners[3 * f + k] = soup.triangles[f][k];
  }
  m.a_.positions = std::move(soup.positions);
  soup.triangles.clear();
  RETURN_IF_ERROR(m.LinkTwins(source));
  m.NumberEdges();
  m.MeasureCorners();
  RETURN_IF_ERROR(m.WalkVertexFans(source));
  return m;
}

absl::Status Mesh::LinkTwins(std::string_view source) {
  const size_t nh = a_.corners.size();
  // A directed edge used twice means a non-manifold edge or two neighbours
  // with opposite orientation; both are rejected. The half-edges of one edge
  // are found by sorting (a hash map of directed edges was a large part of
  // loading a million-face mesh); the clash reported is the first in
  // half-edge order, as a scan in that order would meet it.
  EdgeUses by_edge(nh);
  for (HalfedgeId h = 0; h < nh; ++h) {
    by_edge[h] = {UndirectedEdgeKey(tail(h), head(h)), h};
  }
  SortEdgeUses(by_edge, num_vertices());
  a_.twin.assign(nh, kNone);
  HalfedgeId clash_first = kNone, clash_second = kNone;
  ForEachEdge(by_edge, [&](size_t i, size_t j) {
    HalfedgeId first[2] = {kNone, kNone};  // per direction, in half-edge order
    for (size_t u = i; u < j; ++u) {
      const HalfedgeId h = by_edge[u].second;
      const int direction = tail(h) < head(h);
      if (first[direction] == kNone) {
        first[direction] = h;
      } else if (h < clash_second) {
        clash_first = first[direction];
        clash_second = h;
      }
    }
    if (first[0] != kNone && first[1] != kNone) {
      a_.twin[first[0]] = first[1];
      a_.twin[first[1]] = first[0];
    }
  });
  if (clash_second != kNone) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: edge (%u, %u) is used in the same direction by faces %u and %u: the mesh is "
        "non-manifold there or its faces are inconsistently oriented",
        source, tail(clash_second), head(clash_second), face(clash_first), face(clash_second)));
  }
  return absl::OkStatus();
}

void Mesh::NumberEdges() {
  const size_t nh = a_.corners.size();
  a_.edge.assign(nh, kNone);
  for (HalfedgeId h = 0; h < nh; ++h) {
    if (a_.edge[h] == kNone) {
      EdgeId e = static_cast<EdgeId>(a_.edge_halfedge.size());
      a_.edge_halfedge.push_back(h);
      a_.edge[h] = e;
      if (a_.twin[h] != kNone) a_.edge[a_.twin[h]] = e;
    }
  }
}

void Mesh::MeasureCorners() {
  const size_t nh = a_.corners.size();
  a_.length.resize(nh);
  for (HalfedgeId h = 0; h < nh; ++h) {
    a_.length[h] = Distance(position(tail(h)), position(head(h)));
  }
  a_.corner_angle.resize(nh);
  for (HalfedgeId h = 0; h < nh; ++h) {
    // At tail(h): sides h and prev(h); opposite side next(h).
    a_.corner_angle[h] = AngleFromLengths(a_.length[h], a_.length[prev(h)], a_.length[next(h)]);
  }
}

absl::Status Mesh::WalkVertexFans(std::string_view source) {
  const size_t nv = a_.positions.size(), nh = a_.corners.size();
  // Rotation start: an outgoing boundary half-edge if there is one.
  a_.vertex_halfedge.assign(nv, kNone);
  a_.flags.assign(nv, 0);
  std::vector<uint32_t> outgoing_count(nv, 0);
  for (HalfedgeId h = 0; h < nh; ++h) {
    VertexId v = tail(h);
    ++outgoing_count[v];
    if (a_.twin[h] == kNone) {
      a_.vertex_halfedge[v] = h;
      a_.flags[v] |= kBoundary;
    } else if (a_.vertex_halfedge[v] == kNone) {
      a_.vertex_halfedge[v] = h;
    }
  }
  // A boundary vertex can have only one outgoing boundary half-edge in a
  // single fan; walking the fan must reach every outgoing half-edge.
  a_.polar_angle.assign(nh, 0);
  a_.total_angle.assign(nv, 0);
  for (VertexId v = 0; v < nv; ++v) {
    HalfedgeId start = a_.vertex_halfedge[v];
    if (start == kNone) continue;
    double angle = 0;
    uint32_t visited = 0;
    HalfedgeId h = start;
    do {
      a_.polar_angle[h] = angle;
      angle += a_.corner_angle[h];
      ++visited;
      h = rotate(h);
    } while (h != kNone && h != start && visited <= outgoing_count[v]);
    if (visited != outgoing_count[v]) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s: vertex %u is non-manifold: its faces form more than one fan (%u of %u faces "
          "reachable around it)",
          source, v, visited, outgoing_count[v]));
    }
    a_.total_angle[v] = angle;
    if (!(a_.flags[v] & kBoundary) && angle > 2 * std::numbers::pi * (1 + 1e-10)) {
      a_.flags[v] |= kSaddle;
    }
  }
  return absl::OkStatus();
}

uint64_t Mesh::memory_bytes() const {
  auto bytes = [](const auto& v) { return uint64_t{v.capacity()} * sizeof(v[0]); };
  return bytes(a_.positions) + bytes(a_.corners) + bytes(a_.twin) + bytes(a_.edge) +
         bytes(a_.edge_halfedge) + bytes(a_.length) + bytes(a_.corner_angle) +
         bytes(a_.polar_angle) + bytes(a_.vertex_halfedge) + bytes(a_.total_angle) +
         bytes(a_.flags);
}

uint64_t Mesh::EstimateMemoryBytes(uint64_t vertices, uint64_t faces) {
  const uint64_t halfedges = 3 * faces, edges = halfedges / 2;
  const uint64_t per_vertex = sizeof(Vec3) + sizeof(HalfedgeId) + sizeof(double) + sizeof(uint8_t);
  // corners, twin, edge; length, corner_angle, polar_angle.
  const uint64_t per_halfedge =
      sizeof(VertexId) + sizeof(HalfedgeId) + sizeof(EdgeId) + 3 * sizeof(double);
  return vertices * per_vertex + halfedges * per_halfedge + edges * sizeof(HalfedgeId);
}

absl::Status Mesh::CheckConsistency() const {
  // next and prev are arithmetic on ids, so only the stored arrays can
  // disagree. Faces are walked corner by corner: no division per half-edge.
  for (FaceId f = 0; f < num_faces(); ++f) {
    for (int k = 0; k < 3; ++k) {
      const HalfedgeId h = 3 * f + k;
      const HalfedgeId t = a_.twin[h];
      if (t == kNone) continue;
      if (a_.twin[t] != h) {
        return absl::InternalError(
            absl::StrFormat("twin of twin of half-edge %u is not itself", h));
      }
      if (tail(t) != a_.corners[3 * f + (k + 1) % 3] || head(t) != a_.corners[h]) {
        return absl::InternalError(absl::StrFormat("half-edge %u and its twin disagree", h));
      }
      if (a_.edge[t] != a_.edge[h]) return absl::InternalError("twins have different edge ids");
    }
    // A face with coincident corners has no meaningful angles.
    const double* length = &a_.length[3 * f];
    if (length[0] == 0 || length[1] == 0 || length[2] == 0) continue;
    const double* angle = &a_.corner_angle[3 * f];
    const double sum = angle[0] + angle[1] + angle[2];
    if (std::abs(sum - std::numbers::pi) > 1e-6) {
      return absl::InternalError(absl::StrFormat("angles of face %u sum to %.9f", f, sum));
    }
  }
  return absl::OkStatus();
}

absl::StatusOr<Mesh> Mesh::FromArrays(Arrays a, std::string_view source) {
  const size_t nv = a.positions.size(), nh = a.corners.size(), ne = a.edge_halfedge.size();
  auto damaged = [&](absl::string_view what) {
    return absl::DataLossError(absl::StrFormat("%s: mesh arrays are damaged: %s", source, what));
  };
  if (nv >= kNone || nh >= kNone || nh % 3 != 0) return damaged("element counts");
  if (a.twin.size() != nh || a.edge.size() != nh || a.length.size() != nh ||
      a.corner_angle.size() != nh || a.polar_angle.size() != nh || a.vertex_halfedge.size() != nv ||
      a.total_angle.size() != nv || a.flags.size() != nv) {
    return damaged("array sizes disagree");
  }
  auto in_range = [](const std::vector<uint32_t>& ids, size_t size, bool none_ok) {
    return std::all_of(ids.begin(), ids.end(),
                       [&](uint32_t i) { return i < size || (none_ok && i == kNone); });
  };
  if (!in_range(a.corners, nv, false)) return damaged("a face corner is out of range");
  if (!in_range(a.twin, nh, true) || !in_range(a.edge_halfedge, nh, false) ||
      !in_range(a.vertex_halfedge, nh, true)) {
    return damaged("a half-edge id is out of range");
  }
  if (!in_range(a.edge, ne, false)) return damaged("an edge id is out of range");
  Mesh m;
  m.a_ = std::move(a);
  if (absl::Status s = m.CheckConsistency(); !s.ok()) return damaged(s.message());
  return m;
}

uint64_t MeshFingerprint(const Mesh& mesh) {
  XXH3_state_t* state = XXH3_createState();
  XXH3_64bits_reset(state);
  const uint64_t counts[2] = {mesh.num_vertices(), mesh.num_faces()};
  XXH3_64bits_update(state, counts, sizeof(counts));
  XXH3_64bits_update(state, mesh.positions().data(), mesh.positions().size() * sizeof(Vec3));
  XXH3_64bits_update(state, mesh.corners().data(), mesh.corners().size() * sizeof(VertexId));
  uint64_t hash = XXH3_64bits_digest(state);
  XXH3_freeState(state);
  return hash;
}

}  // namespace geodesic
