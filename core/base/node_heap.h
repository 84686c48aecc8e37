// A min-heap of graph nodes keyed by distance, with decrease-key. Each node
// is in it at most once, so it holds the search frontier rather than every
// improvement a lazy heap would keep, and it is 4-ary: a sift-down compares
// four children that share a cache line, over half the levels of a binary
// heap.
#ifndef GEODESIC_CORE_BASE_NODE_HEAP_H_
#define GEODESIC_CORE_BASE_NODE_HEAP_H_

#include <cstdint>
#include <utility>
#include <vector>

namespace geodesic {

inline constexpr uint32_t kNotInHeap = ~0u;

// `SlotOf` maps a node to a uint32_t& where the heap keeps the node's index
// in it (kNotInHeap when absent); the caller sets it to kNotInHeap before a
// node is first pushed. Keeping it in the caller's own per-node records lets
// a search that touches few nodes skip clearing an array over all of them.
template <typename SlotOf>
class BasicNodeHeap {
 public:
  explicit BasicNodeHeap(SlotOf slot_of = SlotOf()) : slot_of_(std::move(slot_of)) {}

  void Clear() { entries_.clear(); }
  bool empty() const { return entries_.empty(); }
  size_t size() const { return entries_.size(); }
  uint32_t top() const { return entries_.front().node; }
  double top_key() const { return entries_.front().key; }

  // Inserts `node`, or lowers its key if it is in the heap with a larger one.
  void Push(uint32_t node, double key) {
    uint32_t i = slot_of_(node);
    if (i == kNotInHeap) {
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
    slot_of_(entries_.front().node) = kNotInHeap;
    const Entry last = entries_.back();
    entries_.pop_back();
    if (!entries_.empty()) SiftDown(0, last);
  }

 protected:
  SlotOf& slot_of() { return slot_of_; }

 private:
  struct Entry {
    double key;
    uint32_t node;
  };

  void Place(uint32_t i, const Entry& e) {
    entries_[i] = e;
    slot_of_(e.node) = i;
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

  SlotOf slot_of_;
  std::vector<Entry> entries_;
};

// Slots in an array over all nodes.
struct SlotArray {
  std::vector<uint32_t> slots;
  uint32_t& operator()(uint32_t node) { return slots[node]; }
};

// For searches that visit the whole graph anyway.
class NodeHeap : public BasicNodeHeap<SlotArray> {
 public:
  // Empties the heap for nodes 0..nodes-1.
  void Reset(size_t nodes) {
    Clear();
    slot_of().slots.assign(nodes, kNotInHeap);
  }
};

}  // namespace geodesic

#endif  // GEODESIC_CORE_BASE_NODE_HEAP_H_
