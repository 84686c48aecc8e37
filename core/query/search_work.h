// What a graph search did, counted rather than timed: a change that makes a
// search do more work shows here on any machine, by the same count every
// run, where a clock on a shared machine may not see it
// (tests/core/search_work_test.cc pins these on the bundled mesh).
//
// Each search counts into plain locals of its own (no atomics, nothing
// shared), so the counts cost a few register adds per node taken out.
#ifndef GEODESIC_CORE_QUERY_SEARCH_WORK_H_
#define GEODESIC_CORE_QUERY_SEARCH_WORK_H_

#include <cstdint>

namespace geodesic {

struct SearchWork {
  // Edges whose target's label the search compared against (a matrix
  // sweep's edge counts once for all its lanes: it is read once).
  uint64_t relaxed = 0;
  // Labels set or lowered, a seed's included: per lane for a matrix sweep.
  uint64_t improved = 0;
  // Queue insertions and key decreases, and nodes taken out of the queue
  // (stale entries and nodes past a distance limit included: each costs a
  // queue operation all the same).
  uint64_t pushes = 0;
  uint64_t pops = 0;
  // Bytes of the graph read: each edge record relaxed at its own size
  // (sizeof(DggEdge), 16, or a compact copy's 12), plus the two offsets
  // (8 bytes each) that locate the edge list of each node that relaxed a
  // run of its edges. A fan a search reads comes from its own scratch or
  // with the edge record, so it adds nothing; nor do prefetches, which
  // read what the search reads again a few nodes later.
  uint64_t graph_bytes = 0;

  SearchWork& operator+=(const SearchWork& o) {
    relaxed += o.relaxed;
    improved += o.improved;
    pushes += o.pushes;
    pops += o.pops;
    graph_bytes += o.graph_bytes;
    return *this;
  }
};

// graph_bytes of a search that relaxed `relaxed` edges of `edge_bytes` each
// from `expanded` nodes.
inline uint64_t GraphBytesRead(uint64_t relaxed, uint64_t edge_bytes, uint64_t expanded) {
  return relaxed * edge_bytes + expanded * 2 * sizeof(uint64_t);
}

}  // namespace geodesic

#endif  // GEODESIC_CORE_QUERY_SEARCH_WORK_H_
