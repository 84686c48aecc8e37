#include "core/mesh.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <numbers>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"

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

absl::StatusOr<Mesh> Mesh::Build(TriangleSoup soup, std::string_view source) {
  Mesh m;
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
  m.corners_.resize(3 * nf);
  for (size_t f = 0; f < nf; ++f) {
    const auto& t = soup.triangles[f];
    for (int k = 0; k < 3; ++k) {
      if (t[k] >= nv) {
        return absl::InvalidArgumentError(
            absl::StrFormat("%s: face %u refers to vertex %u, but there are only %u vertices",
                            source, f, t[k], nv));
      }
      m.corners_[3 * f + k] = t[k];
    }
    if (t[0] == t[1] || t[1] == t[2] || t[0] == t[2]) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s: face %u repeats a vertex (%u %u %u)", source, f, t[0], t[1], t[2]));
    }
  }
  m.positions_ = std::move(soup.positions);
  soup.triangles.clear();

  const size_t nh = 3 * nf;
  // Twins and edge ids. A directed edge used twice means a non-manifold edge
  // or two neighbours with opposite orientation; both are rejected. The
  // half-edges of one edge are found by sorting (a hash map of directed
  // edges took a third of a million-face load); the clash reported is the
  // first in half-edge order, as a scan in that order would meet it.
  EdgeUses by_edge(nh);
  for (HalfedgeId h = 0; h < nh; ++h) {
    by_edge[h] = {UndirectedEdgeKey(m.tail(h), m.head(h)), h};
  }
  SortEdgeUses(by_edge, m.num_vertices());
  m.twin_.assign(nh, kNone);
  HalfedgeId clash_first = kNone, clash_second = kNone;
  ForEachEdge(by_edge, [&](size_t i, size_t j) {
    HalfedgeId first[2] = {kNone, kNone};  // per direction, in half-edge order
    for (size_t u = i; u < j; ++u) {
      const HalfedgeId h = by_edge[u].second;
      const int direction = m.tail(h) < m.head(h);
      if (first[direction] == kNone) {
        first[direction] = h;
      } else if (h < clash_second) {
        clash_first = first[direction];
        clash_second = h;
      }
    }
    if (first[0] != kNone && first[1] != kNone) {
      m.twin_[first[0]] = first[1];
      m.twin_[first[1]] = first[0];
    }
  });
  if (clash_second != kNone) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: edge (%u, %u) is used in the same direction by faces %u and %u: the mesh is "
        "non-manifold there or its faces are inconsistently oriented",
        source, m.tail(clash_second), m.head(clash_second), face(clash_first), face(clash_second)));
  }
  by_edge = {};
  m.edge_.assign(nh, kNone);
  for (HalfedgeId h = 0; h < nh; ++h) {
    if (m.edge_[h] == kNone) {
      EdgeId e = static_cast<EdgeId>(m.edge_halfedge_.size());
      m.edge_halfedge_.push_back(h);
      m.edge_[h] = e;
      if (m.twin_[h] != kNone) m.edge_[m.twin_[h]] = e;
    }
  }

  // Lengths and corner angles.
  m.length_.resize(nh);
  for (HalfedgeId h = 0; h < nh; ++h) {
    m.length_[h] = Distance(m.position(m.tail(h)), m.position(m.head(h)));
  }
  m.corner_angle_.resize(nh);
  for (HalfedgeId h = 0; h < nh; ++h) {
    // At tail(h): sides h and prev(h); opposite side next(h).
    m.corner_angle_[h] = AngleFromLengths(m.length_[h], m.length_[prev(h)], m.length_[next(h)]);
  }

  // Vertex rotation start: an outgoing boundary half-edge if there is one.
  m.vertex_halfedge_.assign(nv, kNone);
  m.flags_.assign(nv, 0);
  std::vector<uint32_t> outgoing_count(nv, 0);
  for (HalfedgeId h = 0; h < nh; ++h) {
    VertexId v = m.tail(h);
    ++outgoing_count[v];
    if (m.twin_[h] == kNone) {
      m.vertex_halfedge_[v] = h;
      m.flags_[v] |= kBoundary;
    } else if (m.vertex_halfedge_[v] == kNone) {
      m.vertex_halfedge_[v] = h;
    }
  }
  // A boundary vertex can have only one outgoing boundary half-edge in a
  // single fan; walking the fan must reach every outgoing half-edge.
  m.polar_angle_.assign(nh, 0);
  m.total_angle_.assign(nv, 0);
  for (VertexId v = 0; v < nv; ++v) {
    HalfedgeId start = m.vertex_halfedge_[v];
    if (start == kNone) continue;
    double angle = 0;
    uint32_t visited = 0;
    HalfedgeId h = start;
    do {
      m.polar_angle_[h] = angle;
      angle += m.corner_angle_[h];
      ++visited;
      h = m.rotate(h);
    } while (h != kNone && h != start && visited <= outgoing_count[v]);
    if (visited != outgoing_count[v]) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s: vertex %u is non-manifold: its faces form more than one fan (%u of %u faces "
          "reachable around it)",
          source, v, visited, outgoing_count[v]));
    }
    m.total_angle_[v] = angle;
    if (!(m.flags_[v] & kBoundary) && angle > 2 * std::numbers::pi * (1 + 1e-10)) {
      m.flags_[v] |= kSaddle;
    }
  }
  return m;
}

absl::Status Mesh::CheckConsistency() const {
  for (HalfedgeId h = 0; h < num_halfedges(); ++h) {
    if (next(next(next(h))) != h) return absl::InternalError("next does not cycle in 3");
    if (prev(next(h)) != h) return absl::InternalError("prev is not the inverse of next");
    HalfedgeId t = twin_[h];
    if (t != kNone) {
      if (twin_[t] != h) {
        return absl::InternalError(
            absl::StrFormat("twin of twin of half-edge %u is not itself", h));
      }
      if (tail(t) != head(h) || head(t) != tail(h)) {
        return absl::InternalError(absl::StrFormat("half-edge %u and its twin disagree", h));
      }
      if (edge_[t] != edge_[h]) return absl::InternalError("twins have different edge ids");
    }
  }
  for (FaceId f = 0; f < num_faces(); ++f) {
    // A face with coincident corners has no meaningful angles.
    if (length_[3 * f] == 0 || length_[3 * f + 1] == 0 || length_[3 * f + 2] == 0) continue;
    double sum = corner_angle_[3 * f] + corner_angle_[3 * f + 1] + corner_angle_[3 * f + 2];
    if (std::abs(sum - std::numbers::pi) > 1e-6) {
      return absl::InternalError(absl::StrFormat("angles of face %u sum to %.9f", f, sum));
    }
  }
  return absl::OkStatus();
}

}  // namespace geodesic
