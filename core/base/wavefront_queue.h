// The queue of a window propagation: most items need only rough order, a
// few need exact order against all of them.
//
// Windows only have to be taken out roughly by distance: every trim reads
// upper bounds that any real route gives, so the order decides how much is
// trimmed, not what is right. A vertex that becomes a pseudo-source must
// wait for every item nearer than its distance, since it emits once, when
// that distance is final. So loose items (windows) sit in buckets of keys
// [k * width, (k + 1) * width) and leave the lowest bucket last-in first-out,
// and exact items (vertices), with the loose ones whose bucket has already
// been passed or lies beyond the ring, wait in a radix heap; an exact item
// leaves once its key is below the lowest bucket's floor. Last-in first-out
// takes a window's children while their face is still in cache, and a push
// or pop is a vector append or removal. What that gained over one exact
// order, for a few more windows, is in bench/notes.md ("Exact engine").
#ifndef GEODESIC_CORE_BASE_WAVEFRONT_QUEUE_H_
#define GEODESIC_CORE_BASE_WAVEFRONT_QUEUE_H_

#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <utility>
#include <vector>

#include "core/base/radix_heap.h"

namespace geodesic {

template <typename Value>
class WavefrontQueue {
 public:
  // Buckets ahead of the lowest one that loose items may use; farther keys
  // wait in the heap. A wavefront's queued windows span a face or two.
  static constexpr size_t kRing = 256;

  // Empties the queue. Loose items use buckets `width` wide; a width that is
  // not positive and finite puts every item in exact order.
  void Reset(double width) {
    Clear();
    loose_ = width > 0 && std::isfinite(width);
    width_ = loose_ ? width : 1;
    inverse_width_ = 1 / width_;
  }

  void Clear() {
    for (auto& bucket : ring_) bucket.clear();
    heap_.Clear();
    heap_min_known_ = false;
    in_ring_ = 0;
    current_ = 0;
  }

  bool empty() const { return in_ring_ == 0 && heap_.empty(); }
  size_t size() const { return in_ring_ + heap_.size(); }
  uint64_t memory_bytes() const {
    uint64_t total = heap_.memory_bytes();
    for (const auto& bucket : ring_) total += bucket.capacity() * sizeof(Value);
    return total;
  }

  // Leaves after every item with a smaller key, and before any larger one.
  void PushExact(double key, const Value& value) { ToHeap(key, value); }

  // Leaves with the items of its bucket, in no order among them.
  void PushLoose(double key, const Value& value) {
    const double at = key * inverse_width_;
    // The comparisons keep NaN and keys past the ring out of the cast.
    if (loose_ && at >= static_cast<double>(current_) &&
        at < static_cast<double>(current_ + kRing)) {
      ring_[static_cast<uint64_t>(at) % kRing].push_back(value);
      ++in_ring_;
    } else {
      ToHeap(key, value);
    }
  }

  // The next item and a key no larger than any still queued: an exact
  // item's own key, a loose one's bucket floor. The queue must not be empty.
  std::pair<double, Value> Pop() {
    if (in_ring_ > 0) {
      while (ring_[current_ % kRing].empty()) ++current_;
      const double floor = current_ * width_;
      if (heap_.empty() || HeapMin() >= floor) {
        std::vector<Value>& bucket = ring_[current_ % kRing];
        const Value value = bucket.back();
        bucket.pop_back();
        --in_ring_;
        return {floor, value};
      }
    }
    const auto item = heap_.Pop();
    heap_min_known_ = false;
    // With the ring empty, every key still queued is at least this one: the
    // ring can start at its bucket, so that items pushed from it fit.
    const double at = item.first * inverse_width_;
    if (in_ring_ == 0 && at >= static_cast<double>(current_) && at < 0x1p62) {
      current_ = static_cast<uint64_t>(at);
    }
    return item;
  }

  // The value Pop will most likely return next, when that is cheap to tell
  // (nullptr otherwise), for fetching what it needs ahead of time.
  const Value* PeekNext() const {
    const std::vector<Value>& bucket = ring_[current_ % kRing];
    if (!bucket.empty()) return &bucket.back();
    return in_ring_ > 0 ? nullptr : heap_.PeekNext();
  }

 private:
  void ToHeap(double key, const Value& value) {
    heap_.Push(key, value);
    heap_min_known_ = false;
  }

  // The heap's least key, remembered between its pushes and pops: a bucket
  // of loose items compares with it on every pop.
  double HeapMin() {
    if (!heap_min_known_) {
      heap_min_ = heap_.PeekKey();
      heap_min_known_ = true;
    }
    return heap_min_;
  }

  std::array<std::vector<Value>, kRing> ring_;
  RadixHeap<Value> heap_;
  size_t in_ring_ = 0;
  uint64_t current_ = 0;  // the lowest bucket that may hold items
  bool loose_ = false;
  bool heap_min_known_ = false;
  double heap_min_ = 0;
  double width_ = 1, inverse_width_ = 1;
};

}  // namespace geodesic

#endif  // GEODESIC_CORE_BASE_WAVEFRONT_QUEUE_H_
