// A monotone priority queue of non-negative double keys (a radix heap,
// Ahuja, Mehlhorn, Orlin & Tarjan 1990). Wavefront propagations pop keys in
// non-decreasing order, and every key they push is at least the last one
// popped; under that promise a radix heap does O(1) work per push and an
// amortised O(log of the key's bit width) per pop, without the sift-downs
// (and their unpredictable branches) of a comparison heap.
//
// Non-negative doubles order like their bit patterns read as unsigned
// integers, so the key's bits are the radix. An item sits in the bucket named
// by the highest bit in which its key differs from the last popped key; all of
// bucket 0 equals that key. A pop from an empty bucket 0 takes the smallest
// key of the first non-empty bucket as the new last key and redistributes
// that bucket, whose items all land in lower buckets.
#ifndef GEODESIC_CORE_BASE_RADIX_HEAP_H_
#define GEODESIC_CORE_BASE_RADIX_HEAP_H_

#include <algorithm>
#include <array>
#include <bit>
#include <cstdint>
#include <limits>
#include <utility>
#include <vector>

namespace geodesic {

template <typename Value>
class RadixHeap {
 public:
  bool empty() const { return size_ == 0; }
  size_t size() const { return size_; }
  uint64_t memory_bytes() const {
    uint64_t total = 0;
    for (const auto& bucket : buckets_) total += bucket.capacity() * sizeof(Entry);
    return total;
  }

  void Clear() {
    for (auto& bucket : buckets_) bucket.clear();
    occupied_ = 0;
    size_ = 0;
    last_ = 0;
  }

  // A key below the last popped one (rounding in the caller's geometry) is
  // raised to it, so the order stays monotone. NaN counts as +inf.
  void Push(double key, const Value& value) {
    uint64_t bits = key > 0 ? std::bit_cast<uint64_t>(key) : 0;
    if (key != key) bits = std::bit_cast<uint64_t>(std::numeric_limits<double>::infinity());
    bits = std::max(bits, last_);
    Place({bits, value});
    ++size_;
  }

  // The value Pop will most likely return next, when that is cheap to tell
  // (nullptr otherwise): pushes before that Pop may still come first. For
  // fetching what the next item needs while the current one is processed.
  const Value* PeekNext() const {
    if (!buckets_[0].empty()) return &buckets_[0].back().value;
    if (occupied_ == 0) return nullptr;
    // The next Refill takes the least entry of the lowest bucket; a few are
    // quickly scanned.
    const std::vector<Entry>& lowest = buckets_[1 + std::countr_zero(occupied_)];
    return lowest.size() > kPeekScan ? nullptr : &Least(lowest).value;
  }

  // The smallest key and its value; the heap must not be empty.
  std::pair<double, Value> Pop() {
    if (buckets_[0].empty()) Refill();
    Entry e = buckets_[0].back();
    buckets_[0].pop_back();
    --size_;
    return {std::bit_cast<double>(e.bits), e.value};
  }

 private:
  static constexpr size_t kPeekScan = 8;
  struct Entry {
    uint64_t bits;
    Value value;
  };

  // The entry of a non-empty bucket with the smallest key.
  static const Entry& Least(const std::vector<Entry>& bucket) {
    return *std::min_element(bucket.begin(), bucket.end(),
                             [](const Entry& a, const Entry& b) { return a.bits < b.bits; });
  }

  size_t BucketOf(uint64_t bits) const {
    return bits == last_ ? 0 : 64 - std::countl_zero(bits ^ last_);
  }

  void Place(const Entry& e) {
    const size_t b = BucketOf(e.bits);
    buckets_[b].push_back(e);
    if (b > 0) occupied_ |= uint64_t{1} << (b - 1);
  }

  void Refill() {
    const size_t i = 1 + std::countr_zero(occupied_);
    occupied_ &= ~(uint64_t{1} << (i - 1));
    std::vector<Entry>& from = buckets_[i];
    last_ = Least(from).bits;
    for (const Entry& e : from) Place(e);
    from.clear();
  }

  std::array<std::vector<Entry>, 65> buckets_;
  uint64_t occupied_ = 0;  // bit b - 1 set: bucket b (b >= 1) is not empty
  size_t size_ = 0;
  uint64_t last_ = 0;
};

}  // namespace geodesic

#endif  // GEODESIC_CORE_BASE_RADIX_HEAP_H_
