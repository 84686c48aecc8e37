#include "core/mesh/mesh_diagnostics.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numeric>
#include <string>
#include <vector>

#include "absl/container/flat_hash_map.h"
#include "absl/container/flat_hash_set.h"
#include "absl/strings/str_format.h"
#include "core/mesh/corner_fans.h"
#include "nlohmann/json.hpp"

namespace geodesic {
namespace {

double BoundingBoxDiagonal(const std::vector<Vec3>& positions) {
  Vec3 lo{INFINITY, INFINITY, INFINITY}, hi{-INFINITY, -INFINITY, -INFINITY};
  for (const Vec3& p : positions) {
    lo = {std::min(lo.x, p.x), std::min(lo.y, p.y), std::min(lo.z, p.z)};
    hi = {std::max(hi.x, p.x), std::max(hi.y, p.y), std::max(hi.z, p.z)};
  }
  return positions.empty() ? 0 : Distance(lo, hi);
}

uint64_t CountDuplicateVertices(const std::vector<Vec3>& positions) {
  const size_t nv = positions.size();
  std::vector<uint32_t> order(nv);
  std::iota(order.begin(), order.end(), 0);
  auto key = [&](uint32_t i) {
    const Vec3& p = positions[i];
    return std::tie(p.x, p.y, p.z);
  };
  std::sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) { return key(a) < key(b); });
  uint64_t duplicates = 0;
  for (size_t i = 1; i < nv; ++i) duplicates += key(order[i]) == key(order[i - 1]);
  return duplicates;
}

// What one pass over the sorted edge uses finds.
struct EdgeCensus {
  std::vector<uint32_t> edge_of_corner;  // edge id of each corner's outgoing edge
  DisjointSets boundary_sets;            // vertices joined by boundary edges
  std::vector<uint8_t> on_boundary;
  double edge_sum = 0, edge_min = INFINITY;
  uint64_t edge_count = 0, twice_directed = 0, non_manifold_edges = 0;
};

// Edge counts, boundary and non-manifold edges and repeated directed edges
// from one pass over the sorted edge uses (hash maps keyed by edge took most
// of a load on million-face meshes).
EdgeCensus TakeEdgeCensus(const TriangleSoup& soup, const EdgeUses& uses) {
  const size_t nv = soup.positions.size(), nf = soup.triangles.size();
  EdgeCensus c{std::vector<uint32_t>(3 * nf, kNone), DisjointSets(nv), std::vector<uint8_t>(nv, 0)};
  auto from_of = [&](uint32_t corner) { return soup.triangles[corner / 3][corner % 3]; };
  ForEachEdge(uses, [&](size_t i, size_t j) {
    const VertexId a = uses[i].first >> 32, b = uses[i].first & 0xffffffffu;
    const double len = Distance(soup.positions[a], soup.positions[b]);
    c.edge_sum += len;
    c.edge_min = std::min(c.edge_min, len);
    int forward = 0;  // uses walking it from a (the smaller id) to b
    for (size_t u = i; u < j; ++u) {
      c.edge_of_corner[uses[u].second] = static_cast<uint32_t>(c.edge_count);
      forward += from_of(uses[u].second) == a;
    }
    ++c.edge_count;
    const size_t count = j - i;
    c.twice_directed += (forward > 1) + (static_cast<int>(count) - forward > 1);
    if (count > 2) ++c.non_manifold_edges;
    if (count == 1) {
      c.boundary_sets.Union(a, b);
      c.on_boundary[a] = c.on_boundary[b] = 1;
    }
  });
  return c;
}

// Zero-area and near-degenerate faces and the anisotropy of the others;
// needs d->bbox_diagonal for the area floor.
void MeasureFaceShapes(const TriangleSoup& soup, MeshDiagnostics* d) {
  std::vector<double> anisotropy;
  anisotropy.reserve(soup.triangles.size());
  d->zero_area_faces = d->near_degenerate_faces = 0;
  const double area_floor = 1e-12 * d->bbox_diagonal * d->bbox_diagonal;
  for (const auto& t : soup.triangles) {
    const Vec3 &a = soup.positions[t[0]], &b = soup.positions[t[1]], &c = soup.positions[t[2]];
    const double area = 0.5 * Norm(Cross(b - a, c - a));
    const bool repeated = t[0] == t[1] || t[1] == t[2] || t[0] == t[2];
    if (repeated || area <= area_floor) {
      ++d->zero_area_faces;
      continue;
    }
    const double la = Distance(b, c), lb = Distance(a, c), lc = Distance(a, b);
    const double inradius = 2 * area / (la + lb + lc);
    const double ratio = std::max({la, lb, lc}) / (2 * std::sqrt(3.0) * inradius);
    anisotropy.push_back(ratio);
    // Near-degenerate: so thin that angles lose most of their precision.
    if (ratio > 1e3) ++d->near_degenerate_faces;
  }
  if (!anisotropy.empty()) {
    d->anisotropy_mean =
        std::accumulate(anisotropy.begin(), anisotropy.end(), 0.0) / anisotropy.size();
    std::sort(anisotropy.begin(), anisotropy.end());
    d->anisotropy_p95 = anisotropy[static_cast<size_t>(0.95 * (anisotropy.size() - 1))];
    d->anisotropy_max = anisotropy.back();
  }
}

// Faces OpenMesh's kernel would refuse: the ones that make an edge carry a
// third face or repeat a directed edge, counted in file order.
uint64_t CountRefusedFaces(const TriangleSoup& soup, const EdgeCensus& edges) {
  // Per edge: bit 0 / 1 set once a kept face walks it from its smaller /
  // larger end, and how many kept faces it has (at most 2), times 4.
  std::vector<uint8_t> accepted(edges.edge_count, 0);
  uint64_t refused = 0;
  for (uint32_t f = 0; f < soup.triangles.size(); ++f) {
    const auto& t = soup.triangles[f];
    bool refuse = t[0] == t[1] || t[1] == t[2] || t[0] == t[2];
    for (int k = 0; k < 3 && !refuse; ++k) {
      const uint32_t e = edges.edge_of_corner[3 * f + k];
      const uint8_t direction = t[k] < t[(k + 1) % 3] ? 1 : 2;
      refuse = (accepted[e] & direction) || accepted[e] >= 8;
    }
    if (refuse) {
      ++refused;
      continue;
    }
    for (int k = 0; k < 3; ++k) {
      const uint32_t e = edges.edge_of_corner[3 * f + k];
      accepted[e] = (accepted[e] | (t[k] < t[(k + 1) % 3] ? 1 : 2)) + 4;
    }
  }
  return refused;
}

// How many sets of `sets` the vertices with member[v] set fall into.
uint64_t CountSetsAmong(DisjointSets& sets, const std::vector<uint8_t>& member) {
  std::vector<uint8_t> root_seen(member.size(), 0);
  uint64_t count = 0;
  for (size_t v = 0; v < member.size(); ++v) {
    if (!member[v]) continue;
    uint32_t r = sets.Find(v);
    if (!root_seen[r]) {
      root_seen[r] = 1;
      ++count;
    }
  }
  return count;
}

// Components of faces sharing a vertex.
uint64_t CountComponents(const TriangleSoup& soup, const std::vector<uint8_t>& used) {
  DisjointSets vertex_sets(soup.positions.size());
  for (const auto& t : soup.triangles) {
    vertex_sets.Union(t[0], t[1]);
    vertex_sets.Union(t[1], t[2]);
  }
  return CountSetsAmong(vertex_sets, used);
}

// The corners around a manifold vertex, joined across its two-face edges,
// form a single fan: count the vertices where they form more.
uint64_t CountNonManifoldVertices(const TriangleSoup& soup, DisjointSets& corners) {
  const size_t nv = soup.positions.size(), nf = soup.triangles.size();
  // A vertex's first fan root, or kPinched once a second fan has been seen:
  // roots are corner ids, below 3 * nf, which the loop's uint32_t holds.
  constexpr uint32_t kPinched = kNone - 1;
  std::vector<uint32_t> first_root(nv, kNone);
  uint64_t pinched = 0;
  for (uint32_t c = 0; c < 3 * nf; ++c) {
    VertexId v = soup.triangles[c / 3][c % 3];
    uint32_t r = corners.Find(c);
    if (first_root[v] == kNone) {
      first_root[v] = r;
    } else if (first_root[v] != r && first_root[v] != kPinched) {
      first_root[v] = kPinched;
      ++pinched;
    }
  }
  return pinched;
}

// Interior vertices whose angle sum exceeds 2 pi.
uint64_t CountSaddleVertices(const TriangleSoup& soup, const std::vector<uint8_t>& used,
                             const std::vector<uint8_t>& on_boundary) {
  const size_t nv = soup.positions.size();
  std::vector<double> angle_sum(nv, 0);
  for (const auto& t : soup.triangles) {
    for (int k = 0; k < 3; ++k) {
      const Vec3& p = soup.positions[t[k]];
      Vec3 u = soup.positions[t[(k + 1) % 3]] - p, w = soup.positions[t[(k + 2) % 3]] - p;
      double nu = Norm(u), nw = Norm(w);
      if (nu > 0 && nw > 0)
        angle_sum[t[k]] += std::acos(std::clamp(Dot(u, w) / (nu * nw), -1.0, 1.0));
    }
  }
  uint64_t saddles = 0;
  for (size_t v = 0; v < nv; ++v) {
    saddles += used[v] && !on_boundary[v] && angle_sum[v] > 2 * std::numbers::pi * (1 + 1e-10);
  }
  return saddles;
}

}  // namespace

void ComputeDiagnostics(const TriangleSoup& soup, MeshDiagnostics* d) {
  const size_t nv = soup.positions.size(), nf = soup.triangles.size();
  d->vertices = nv;
  d->faces = nf;
  d->bbox_diagonal = BoundingBoxDiagonal(soup.positions);
  d->duplicate_vertices = CountDuplicateVertices(soup.positions);
  const EdgeUses uses = SortedEdgeUses(soup);
  std::vector<uint8_t> used(nv, 0);
  for (const auto& t : soup.triangles) used[t[0]] = used[t[1]] = used[t[2]] = 1;
  EdgeCensus edges = TakeEdgeCensus(soup, uses);
  DisjointSets corners = CornerFans(soup, uses);
  MeasureFaceShapes(soup, d);
  d->non_manifold_edges = edges.non_manifold_edges;
  d->edges = edges.edge_count;
  d->mean_edge_length = edges.edge_count ? edges.edge_sum / edges.edge_count : 0;
  d->min_edge_length = edges.edge_count ? edges.edge_min : 0;
  d->isolated_vertices = std::count(used.begin(), used.end(), 0);
  d->faces_refused = CountRefusedFaces(soup, edges);
  d->components = CountComponents(soup, used);
  // Boundary loops: components of the graph of boundary edges.
  d->boundary_loops = CountSetsAmong(edges.boundary_sets, edges.on_boundary);
  d->boundary_vertices = std::count(edges.on_boundary.begin(), edges.on_boundary.end(), 1);
  d->non_manifold_vertices = CountNonManifoldVertices(soup, corners);
  d->manifold =
      d->non_manifold_edges == 0 && d->non_manifold_vertices == 0 && edges.twice_directed == 0;
  // Genus per the manifest: (2 * components - euler - boundary loops) / 2.
  const int64_t euler =
      int64_t(nv - d->isolated_vertices) - int64_t(edges.edge_count) + int64_t(nf);
  d->genus = (2 * int64_t(d->components) - euler - int64_t(d->boundary_loops)) / 2;
  d->saddle_vertices = CountSaddleVertices(soup, used, edges.on_boundary);
}

std::string MeshDiagnostics::ToText() const {
  std::string s;
  s += absl::StrFormat("%s (%s)\n", path, format);
  s += absl::StrFormat("  vertices %u, faces %u, edges %u", vertices, faces, edges);
  if (polygons_triangulated)
    s += absl::StrFormat(" (%u polygons triangulated)", polygons_triangulated);
  s += absl::StrFormat("\n  components %u, boundary loops %u, genus %d%s\n", components,
                       boundary_loops, genus, manifold ? "" : " (not meaningful: non-manifold)");
  s += absl::StrFormat(
      "  isolated vertices %u, duplicate vertices %u, zero-area faces %u, near-degenerate "
      "faces %u\n",
      isolated_vertices, duplicate_vertices, zero_area_faces, near_degenerate_faces);
  s += absl::StrFormat(
      "  non-manifold edges %u, non-manifold vertices %u, faces OpenMesh would refuse %u\n",
      non_manifold_edges, non_manifold_vertices, faces_refused);
  s += absl::StrFormat("  bounding-box diagonal %.6g, edge length mean %.6g min %.6g\n",
                       bbox_diagonal, mean_edge_length, min_edge_length);
  s += absl::StrFormat("  anisotropy mean %.4g, p95 %.4g, max %.4g\n", anisotropy_mean,
                       anisotropy_p95, anisotropy_max);
  s += absl::StrFormat("  saddle vertices %u, boundary vertices %u\n", saddle_vertices,
                       boundary_vertices);
  s += absl::StrFormat("  loaded in %.3f s\n", load_seconds);
  s += mesh_error.empty() ? "  usable for geodesics: yes\n"
                          : absl::StrFormat("  usable for geodesics: no: %s\n", mesh_error);
  return s;
}

std::string MeshDiagnostics::ToJson() const {
  // Ordered: the keys print in the order below, as they always have.
  nlohmann::ordered_json j;
  j["path"] = path;
  j["format"] = format;
  j["vertices"] = vertices;
  j["faces"] = faces;
  j["edges"] = edges;
  j["polygons_triangulated"] = polygons_triangulated;
  j["components"] = components;
  j["boundary_loops"] = boundary_loops;
  j["genus"] = genus;
  j["isolated_vertices"] = isolated_vertices;
  j["duplicate_vertices"] = duplicate_vertices;
  j["zero_area_faces"] = zero_area_faces;
  j["near_degenerate_faces"] = near_degenerate_faces;
  j["non_manifold_edges"] = non_manifold_edges;
  j["non_manifold_vertices"] = non_manifold_vertices;
  j["faces_refused"] = faces_refused;
  j["bbox_diagonal"] = bbox_diagonal;
  j["mean_edge_length"] = mean_edge_length;
  j["min_edge_length"] = min_edge_length;
  j["anisotropy_mean"] = anisotropy_mean;
  j["anisotropy_p95"] = anisotropy_p95;
  j["anisotropy_max"] = anisotropy_max;
  j["saddle_vertices"] = saddle_vertices;
  j["boundary_vertices"] = boundary_vertices;
  j["manifold"] = manifold;
  j["usable"] = mesh_error.empty();
  j["mesh_error"] = mesh_error;
  // To the microsecond, as the report has always given it.
  j["load_seconds"] = std::round(load_seconds * 1e6) / 1e6;
  // A path or message that is not UTF-8 (file names are bytes) gets U+FFFD
  // for the bytes that are not, rather than an exception.
  return j.dump(-1, ' ', /*ensure_ascii=*/false, nlohmann::ordered_json::error_handler_t::replace);
}

}  // namespace geodesic
