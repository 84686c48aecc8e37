// A bucket queue for label-correcting searches with nonnegative edge weights
// (the buckets of Meyer and Sanders' delta-stepping, 2003): nodes are kept in
// buckets of keys [k * width, (k + 1) * width) and taken out bucket by
// bucket, in no order inside one. A push and a pop are a vector append and a
// removal, against a heap's walk over its levels.
//
// The order is only approximate, so a node may be taken out before its label
// is final and must then be taken out again once it improves: the caller
// pushes a node whenever its label improves and skips entries it has already
// handled at their current label. With a width below most edge weights, few
// nodes improve within their own bucket.
#ifndef GEODESIC_CORE_BUCKET_QUEUE_H_
#define GEODESIC_CORE_BUCKET_QUEUE_H_

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <vector>

namespace geodesic {

class BucketQueue {
 public:
  // Empties the queue for keys of at least 0 that are never more than
  // `max_step` above the lowest bucket holding entries: a search pushes a
  // label plus one edge weight, so the largest edge weight (and the largest
  // seed key) bounds that. Both must be positive and finite.
  void Reset(double width, double max_step) {
    inverse_width_ = 1 / width;
    width_ = width;
    const uint64_t needed = static_cast<uint64_t>(std::ceil(max_step / width)) + 2;
    const uint64_t size = std::bit_ceil(needed);
    if (buckets_.size() != size) buckets_.assign(size, {});
    for (auto& b : buckets_) b.clear();
    mask_ = size - 1;
    current_ = 0;
    pending_ = 0;
  }

  bool empty() const { return pending_ == 0; }

  // A key below the current bucket's keys joins the current bucket.
  void Push(uint32_t node, double key) {
    const uint64_t k = std::max(Bucket(key), current_);
    buckets_[k & mask_].push_back(node);
    ++pending_;
  }

  // Takes out a node of the lowest bucket that holds any. Not when empty.
  uint32_t Pop() {
    std::vector<uint32_t>* b = &buckets_[current_ & mask_];
    while (b->empty()) b = &buckets_[++current_ & mask_];
    const uint32_t node = b->back();
    b->pop_back();
    --pending_;
    return node;
  }

  // The node Pop takes out next if it is known without a scan, else `none`:
  // for prefetching.
  uint32_t Peek(uint32_t none) const {
    const std::vector<uint32_t>& b = buckets_[current_ & mask_];
    return b.empty() ? none : b.back();
  }

  // No key still queued is below this (valid after Pop).
  double floor() const { return current_ * width_; }

  // How many buckets the ring holds.
  size_t ring_size() const { return buckets_.size(); }

 private:
  uint64_t Bucket(double key) const { return static_cast<uint64_t>(key * inverse_width_); }

  std::vector<std::vector<uint32_t>> buckets_;
  uint64_t mask_ = 0;
  uint64_t current_ = 0;
  uint64_t pending_ = 0;
  double width_ = 1, inverse_width_ = 1;
};

}  // namespace geodesic

#endif  // GEODESIC_CORE_BUCKET_QUEUE_H_
