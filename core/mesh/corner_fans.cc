#include "core/mesh/corner_fans.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numeric>
#include <string>
#include <vector>

#include "absl/container/flat_hash_map.h"
#include "absl/container/flat_hash_set.h"
#include "absl/strings/str_format.h"

namespace geodesic {

uint32_t CornerOf(const TriangleSoup& soup, uint32_t f, VertexId v) {
  const auto& t = soup.triangles[f];
  return 3 * f + (t[0] == v ? 0 : t[1] == v ? 1 : 2);
}

EdgeUses SortedEdgeUses(const TriangleSoup& soup) {
  EdgeUses uses;
  uses.reserve(3 * soup.triangles.size());
  for (uint32_t f = 0; f < soup.triangles.size(); ++f) {
    const auto& t = soup.triangles[f];
    for (int k = 0; k < 3; ++k) {
      if (t[k] != t[(k + 1) % 3])
        uses.push_back({UndirectedEdgeKey(t[k], t[(k + 1) % 3]), 3 * f + k});
    }
  }
  SortEdgeUses(uses, soup.positions.size());
  return uses;
}

DisjointSets CornerFans(const TriangleSoup& soup, const EdgeUses& uses) {
  DisjointSets fans(3 * soup.triangles.size());
  ForEachEdge(uses, [&](size_t i, size_t j) {
    if (j - i != 2) return;
    const VertexId a = uses[i].first >> 32, b = uses[i].first & 0xffffffffu;
    const uint32_t f0 = uses[i].second / 3, f1 = uses[i + 1].second / 3;
    fans.Union(CornerOf(soup, f0, a), CornerOf(soup, f1, a));
    fans.Union(CornerOf(soup, f0, b), CornerOf(soup, f1, b));
  });
  return fans;
}

std::vector<VertexCopy> SplitNonManifoldVertices(TriangleSoup* soup) {
  const size_t nf = soup->triangles.size();
  DisjointSets corners = CornerFans(*soup, SortedEdgeUses(*soup));
  absl::flat_hash_map<uint64_t, VertexId> copy_of;  // (vertex, fan root) -> id
  std::vector<uint32_t> first_root(soup->positions.size(), kNone);
  std::vector<VertexCopy> copies;
  for (uint32_t c = 0; c < 3 * nf; ++c) {
    VertexId& v = soup->triangles[c / 3][c % 3];
    uint32_t r = corners.Find(c);
    if (first_root[v] == kNone) first_root[v] = r;
    if (first_root[v] == r) continue;
    auto [it, inserted] =
        copy_of.emplace((uint64_t{v} << 32) | r, static_cast<VertexId>(soup->positions.size()));
    if (inserted) {
      soup->positions.push_back(soup->positions[v]);
      copies.push_back({v, it->second});
    }
    v = it->second;
  }
  return copies;
}

}  // namespace geodesic
