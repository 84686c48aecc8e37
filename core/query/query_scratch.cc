#include "core/query/query_scratch.h"

#include <algorithm>

namespace geodesic {
namespace {

// Records kept between queries: 256 KiB, more than most queries touch.
constexpr size_t kKeptRecords = 4096;

}  // namespace

void PairTable::Reset(uint32_t nodes) {
  for (const Record& r : records_) index_[r.node] = 0;
  records_.clear();
  if (index_.size() < nodes) index_.resize(nodes, 0);
  // A query that touched a large part of the graph leaves a large vector;
  // the next ones rarely need it. Up to the index's own size (4 bytes per
  // node) it stays: freeing and regrowing it on every long query on a large
  // graph cost more than the search's page faults.
  const size_t keep = std::max<size_t>(kKeptRecords, nodes * sizeof(uint32_t) / sizeof(Record));
  if (records_.capacity() > keep || records_.capacity() == 0) {
    std::vector<Record>().swap(records_);
    records_.reserve(kKeptRecords);
  }
}

void QueryScratch::PrepareField(size_t nodes, bool labels, LaneFanLayout layout) {
  if (dist.size() < nodes) dist.resize(nodes);
  if (layout == LaneFanLayout::kPacked && fan_packed.size() < nodes) fan_packed.resize(nodes);
  if (layout == LaneFanLayout::kWhole && fan.size() < nodes) fan.resize(nodes);
  if (labels && label.size() < nodes) label.resize(nodes);
}

LaneFanLayout LaneFanLayoutFor(const DggGraph& g) {
  const auto offsets = g.offsets();
  for (uint32_t u = 0; u < g.num_nodes(); ++u) {
    if (offsets[u + 1] - offsets[u] > kMaxPackedDegree) return LaneFanLayout::kWhole;
  }
  return LaneFanLayout::kPacked;
}

void QueryScratch::PrepareLanes(size_t nodes, LaneFanLayout layout) {
  if (lane_dist.size() < nodes) {
    lane_dist.resize(nodes);
    lane_dirty.resize(nodes);
    lanes_clear_but_reached = false;  // the new nodes' lanes are not +inf
  }
  if (layout == LaneFanLayout::kPacked && lane_fan_packed.size() < nodes) {
    lane_fan_packed.resize(nodes);
  }
  if (layout == LaneFanLayout::kWhole && lane_fan.size() < nodes) lane_fan.resize(nodes);
}

uint64_t QueryScratch::bytes() const {
  uint64_t total = sizeof(*this) + pairs.bytes();
  total += dist.capacity() * sizeof(double) + fan.capacity() * sizeof(FanRange) +
           fan_packed.capacity() * sizeof(uint32_t) + label.capacity() * sizeof(uint32_t);
  total += lane_dist.capacity() * sizeof(LaneLabels) + lane_fan.capacity() * sizeof(LaneFans) +
           lane_fan_packed.capacity() * sizeof(PackedLaneFans) + lane_dirty.capacity() +
           lane_reached.capacity() * sizeof(uint32_t);
  if (exact) total += exact->memory_bytes();
  return total;
}

ScratchPool::Lease ScratchPool::Acquire() {
  in_use_.fetch_add(1, std::memory_order_relaxed);
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (!idle_.empty()) {
      Idle reused = std::move(idle_.back());
      idle_.pop_back();
      return Lease(this, std::move(reused.scratch), reused.bytes);
    }
  }
  return Lease(this, std::make_unique<QueryScratch>(), 0);
}

void ScratchPool::Release(std::unique_ptr<QueryScratch> scratch, uint64_t counted) {
  in_use_.fetch_sub(1, std::memory_order_relaxed);
  const uint64_t size = scratch->bytes();
  std::lock_guard<std::mutex> lock(mu_);
  uint64_t total = bytes_.load(std::memory_order_relaxed) - counted;
  if (static_cast<int>(idle_.size()) < keep_idle_) {
    idle_.push_back({std::move(scratch), size});
    total += size;
  }
  bytes_.store(total, std::memory_order_relaxed);
}

int ScratchPool::idle() const {
  std::lock_guard<std::mutex> lock(mu_);
  return static_cast<int>(idle_.size());
}

}  // namespace geodesic
