// A monotone priority queue of non-negative double keys (a radix heap,
// Ahuja, Mehlhorn, Orlin & Tarjan 1990). Wavefront propagations pop keys in
// non-decreasing order, and every key they push is at least the last one
// popped; under that promise a radix heap does O(1) work per push and an
// amortised O(log of the key's bit width) per pop, without the sift-downs
// (and their unpredictable branches) of a comparison heap.
//
// Non-negative doubles order like their bit patterns read as unsigned
// integers, so the key's bits are the radix. An item sits in the bucket named
// by the highest bit in which its key differs from the last key taken out of
// a bucket. A pop from an empty bucket 0 takes the first non-empty bucket:
// a large one is redistributed (its smallest key becomes the new last key and
// its items all land in lower buckets), a small one is sorted into bucket 0.
// Bucket 0 is thus a sorted run of the smallest keys, popped from its end,
// and a push smaller than its largest key is inserted in order; a run grown
// past a bound by such pushes gives its larger half back to the buckets, so
// that an insert moves a bounded number of entries whatever the workload.
// Wavefront keys are distinct doubles, so redistributing alone emptied a
// bucket of a few items on nearly every pop, moving each item some ten times
// on its way down; a sorted run moves it once.
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
  // Buckets of at most kSortedRun items are sorted into the run rather than
  // redistributed: sorting so few costs less than moving each down again.
  // Pushes among the run's keys may grow it to kLongestRun; then it is
  // halved.
  static constexpr size_t kSortedRun = 64;
  static constexpr size_t kLongestRun = 4 * kSortedRun;

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
    popped_ = 0;
  }

  // A key below the last popped one (rounding in the caller's geometry) is
  // raised to it, so the order stays monotone. NaN counts as +inf.
  void Push(double key, const Value& value) {
    uint64_t bits = key > 0 ? std::bit_cast<uint64_t>(key) : 0;
    if (key != key) bits = std::bit_cast<uint64_t>(std::numeric_limits<double>::infinity());
    bits = std::max(bits, popped_);
    std::vector<Entry>& run = buckets_[0];
    if (!run.empty() && bits < run.front().bits) {
      // Within the run: after every larger key, before the smaller ones.
      auto at = std::upper_bound(run.begin(), run.end(), bits,
                                 [](uint64_t b, const Entry& e) { return b > e.bits; });
      run.insert(at, {bits, value});
      if (run.size() > kLongestRun) ShortenRun();
    } else {
      Place({bits, value});
    }
    ++size_;
  }

  // How many entries the sorted run holds; for tests. Inserts keep it within
  // kLongestRun; keys equal to the radix are appended at its end, at no
  // cost, and may take it beyond.
  size_t run_size() const { return buckets_[0].size(); }

  // The value Pop will most likely return next, when that is cheap to tell
  // (nullptr otherwise): pushes before that Pop may still come first. For
  // fetching what the next item needs while the current one is processed.
  const Value* PeekNext() const {
    if (!buckets_[0].empty()) return &buckets_[0].back().value;
    if (occupied_ == 0) return nullptr;
    // The next Refill takes the least entry of the lowest bucket; a few are
    // quickly scanned.
    const std::vector<Entry>& lowest = buckets_[LowestBucket()];
    return lowest.size() > kPeekScan ? nullptr : &Least(lowest).value;
  }

  // The smallest key, as Pop would return it; the heap must not be empty.
  // It scans the lowest bucket when the run is empty, and moves nothing: a
  // refill here would let pushes below the new radix into the run, which
  // could then hand them back to the buckets out of order.
  double PeekKey() const {
    if (!buckets_[0].empty()) return std::bit_cast<double>(buckets_[0].back().bits);
    return std::bit_cast<double>(Least(buckets_[LowestBucket()]).bits);
  }

  // The smallest key and its value; the heap must not be empty.
  std::pair<double, Value> Pop() {
    if (buckets_[0].empty()) Refill();
    Entry e = buckets_[0].back();
    buckets_[0].pop_back();
    --size_;
    popped_ = e.bits;
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

  // The lowest non-empty bucket past the run; some bucket must hold items.
  size_t LowestBucket() const { return 1 + std::countr_zero(occupied_); }

  size_t BucketOf(uint64_t bits) const {
    return bits == last_ ? 0 : 64 - std::countl_zero(bits ^ last_);
  }

  void Place(const Entry& e) {
    const size_t b = BucketOf(e.bits);
    buckets_[b].push_back(e);
    if (b > 0) occupied_ |= uint64_t{1} << (b - 1);
  }

  // Gives the run's larger half (its front) back to the buckets. Those keys
  // exceed every key left in the run and are at least the last key, as the
  // buckets require. They are copied out first: a key equal to the last
  // key is placed in the run itself.
  void ShortenRun() {
    std::vector<Entry>& run = buckets_[0];
    const auto larger_end = run.begin() + (run.size() - run.size() / 2);
    const std::vector<Entry> larger(run.begin(), larger_end);
    run.erase(run.begin(), larger_end);
    for (const Entry& e : larger) Place(e);
  }

  void Refill() {
    const size_t i = LowestBucket();
    occupied_ &= ~(uint64_t{1} << (i - 1));
    std::vector<Entry>& from = buckets_[i];
    if (from.size() <= kSortedRun) {
      // Every other bucket's keys exceed these, so they can be the run. Its
      // smallest key is the new last key: the buckets' items and the pushes
      // to come are all at least that.
      std::sort(from.begin(), from.end(),
                [](const Entry& a, const Entry& b) { return a.bits > b.bits; });
      last_ = from.back().bits;
      buckets_[0].swap(from);
      return;
    }
    last_ = Least(from).bits;
    for (const Entry& e : from) Place(e);
    from.clear();
  }

  std::array<std::vector<Entry>, 65> buckets_;
  uint64_t occupied_ = 0;  // bit b - 1 set: bucket b (b >= 1) is not empty
  size_t size_ = 0;
  uint64_t last_ = 0;    // the radix the buckets' items are placed by
  uint64_t popped_ = 0;  // the last key popped; pushes are raised to it
};

}  // namespace geodesic

#endif  // GEODESIC_CORE_BASE_RADIX_HEAP_H_
