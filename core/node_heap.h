// A min-heap of graph nodes keyed by distance, with decrease-key, for
// Dijkstra over a whole graph. Each node is in it at most once, so it holds
// the search frontier rather than every improvement a lazy heap would keep,
// and it is 4-ary: a sift-down compares four children that share a cache
// line, over half the levels of a binary heap.
#ifndef GEODESIC_CORE_NODE_HEAP_H_
#define GEODESIC_CORE_NODE_HEAP_H_

#include <cstdint>
#include <vector>

namespace geodesic {

class NodeHeap {
 public:
  // Empties the heap for nodes 0..nodes-1.
  void Reset(size_t nodes) {
    entries_.clear();
    position_.assign(nodes, kAbsent);
  }
  bool empty() const { return entries_.empty(); }
  uint32_t top() const { return entries_.front().node; }
  double top_key() const { return entries_.front().key; }

  // Inserts `node`, or lowers its key if it is in the heap with a larger one.
  void Push(uint32_t node, double key) {
    uint32_t i = position_[node];
    if (i == kAbsent) {
      i = static_cast<uint32_t>(entries_.size());
      entries_.push_back({key, node});
    } else if (key < entries_[i].key) {
      entries_[i].key = key;
    } else {
      return;
    }
    SiftUp(i);
  }

  void Pop() {
    position_[entries_.front().node] = kAbsent;
    const Entry last = entries_.back();
    entries_.pop_back();
    if (!entries_.empty()) SiftDown(0, last);
  }

 private:
  struct Entry {
    double key;
    uint32_t node;
  };
  static constexpr uint32_t kAbsent = ~0u;

  void Place(uint32_t i, const Entry& e) {
    entries_[i] = e;
    position_[e.node] = i;
  }
  void SiftUp(uint32_t i) {
    const Entry e = entries_[i];
    while (i > 0) {
      const uint32_t parent = (i - 1) / 4;
      if (!(e.key < entries_[parent].key)) break;
      Place(i, entries_[parent]);
      i = parent;
    }
    Place(i, e);
  }
  // Puts `e` at hole i or below it.
  void SiftDown(uint32_t i, const Entry& e) {
    const uint32_t n = static_cast<uint32_t>(entries_.size());
    while (true) {
      const uint32_t first = 4 * i + 1;
      if (first >= n) break;
      uint32_t best = first;
      const uint32_t end = first + 4 < n ? first + 4 : n;
      for (uint32_t c = first + 1; c < end; ++c) {
        if (entries_[c].key < entries_[best].key) best = c;
      }
      if (!(entries_[best].key < e.key)) break;
      Place(i, entries_[best]);
      i = best;
    }
    Place(i, e);
  }

  std::vector<Entry> entries_;
  std::vector<uint32_t> position_;
};

}  // namespace geodesic

#endif  // GEODESIC_CORE_NODE_HEAP_H_
