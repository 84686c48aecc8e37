// A bucket queue for label-correcting searches with nonnegative edge weights
// (the buckets of Meyer and Sanders' delta-stepping, 2003): nodes are kept in
// buckets of keys [k * width, (k + 1) * width) and taken out bucket by
// bucket, in no order inside one. A push and a pop are a vector append and a
// removal, against a heap's walk over its levels.
//
// The order is only approximate, so a node may be taken out before its label
// is final and must then be taken out again once it improves: the caller
// pushes a node whenever its label improves. A node is queued once at a
// time; moving to a lower bucket leaves an entry behind that is skipped.
// With a width below most edge weights, few nodes improve after they are
// taken out.
#ifndef GEODESIC_CORE_BASE_BUCKET_QUEUE_H_
#define GEODESIC_CORE_BASE_BUCKET_QUEUE_H_

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <vector>

namespace geodesic {

class BucketQueue {
 public:
  // Empties the queue for nodes 0..nodes-1 and keys of at least 0 that are
  // never more than `max_step` above the lowest bucket holding entries: a
  // search pushes a label plus one edge weight, so the largest edge weight
  // (and the largest seed key) bounds that. Both must be positive and finite.
  void Reset(size_t nodes, double width, double max_step) {
    inverse_width_ = 1 / width;
    width_ = width;
    const uint64_t needed = static_cast<uint64_t>(std::ceil(max_step / width)) + 2;
    const uint64_t size = std::bit_ceil(needed);
    if (buckets_.size() != size) buckets_.assign(size, {});
    for (auto& b : buckets_) b.clear();
    // Every node out of the queue is kOut, so a queue run dry is clear
    // already: a sweep near its sources then costs what it reaches, not a
    // pass over every node.
    if (live_ != 0 || bucket_of_.size() != nodes) bucket_of_.assign(nodes, kOut);
    head_ = 0;
    mask_ = size - 1;
    current_ = 0;
    live_ = 0;
  }

  bool empty() const { return live_ == 0; }

  // Queues `node` at `key`, or moves it there. A node already in that
  // bucket stays where it is; one in a higher bucket leaves behind an entry
  // that Pop skips. A key below the current bucket's joins the current one.
  void Push(uint32_t node, double key) {
    const uint64_t k = std::max(Bucket(key), current_);
    uint32_t& at = bucket_of_[node];
    if (at == static_cast<uint32_t>(k)) return;
    if (at == kOut) ++live_;
    at = static_cast<uint32_t>(k);
    buckets_[k & mask_].push_back(node);
  }

  // Queues `node` at `key` unless it is queued at that key's bucket or a
  // lower one: for searches whose node keys are the least of several labels
  // (core/query/field_lanes.h), where a later improvement may be of a higher
  // label. Such keys may lie beyond the ring: they are taken out at its far
  // end, early, which a label-correcting search corrects like any early pop.
  void Lower(uint32_t node, double key) {
    const uint64_t k = std::min(std::max(Bucket(key), current_), current_ + mask_);
    uint32_t& at = bucket_of_[node];
    if (at != kOut && static_cast<uint32_t>(at - static_cast<uint32_t>(current_)) <=
                          static_cast<uint32_t>(k - current_)) {
      return;
    }
    if (at == kOut) ++live_;
    at = static_cast<uint32_t>(k);
    buckets_[k & mask_].push_back(node);
  }

  // Takes out a node of the lowest bucket that holds any. Not when empty.
  uint32_t Pop() {
    while (true) {
      std::vector<uint32_t>* b = &buckets_[current_ & mask_];
      while (b->size() == head_) {
        b->clear();
        head_ = 0;
        b = &buckets_[++current_ & mask_];
      }
      const uint32_t node = (*b)[head_++];
      uint32_t& at = bucket_of_[node];
      if (at != static_cast<uint32_t>(current_)) continue;  // it moved lower
      at = kOut;
      --live_;
      return node;
    }
  }

  // The node Pop takes out `ahead` entries from now, if that entry is known
  // without a scan (it may be one Pop skips), else `none`: for prefetching.
  uint32_t Peek(uint32_t none, size_t ahead = 0) const {
    const std::vector<uint32_t>& b = buckets_[current_ & mask_];
    return head_ + ahead < b.size() ? b[head_ + ahead] : none;
  }

  // No key still queued is below this (valid after Pop).
  double floor() const { return current_ * width_; }

  // How many buckets the ring holds.
  size_t ring_size() const { return buckets_.size(); }

 private:
  uint64_t Bucket(double key) const { return static_cast<uint64_t>(key * inverse_width_); }

  // A bucket index fits 32 bits modulo 2^32: queued keys span far fewer
  // buckets than that.
  static constexpr uint32_t kOut = ~0u;
  std::vector<std::vector<uint32_t>> buckets_;
  std::vector<uint32_t> bucket_of_;  // per node: its live entry's bucket, or kOut
  uint64_t mask_ = 0;
  uint64_t current_ = 0;
  uint64_t live_ = 0;  // queued nodes
  size_t head_ = 0;    // entries of the current bucket before it are out
  double width_ = 1, inverse_width_ = 1;
};

}  // namespace geodesic

#endif  // GEODESIC_CORE_BASE_BUCKET_QUEUE_H_
