// Scratch memory of geodesic queries (core/query/geodesic_engine.cc): what one query needs
// besides the graph, reused by later queries instead of allocated anew.
//
// A GeodesicEngine owns a pool of these. A query leases one for its
// duration, so scratch exists per query in flight, not per thread that ever
// ran one (a server's threads outnumber its concurrent queries), it goes
// with the engine when a graph is evicted, and its bytes are counted.
// Point-to-point searches keep their per-node state in a hash table sized
// to the nodes they touch, not to the graph: a few thousand records on any
// mesh, where a dense array cost 64 bytes per graph node per thread.
#ifndef GEODESIC_CORE_QUERY_QUERY_SCRATCH_H_
#define GEODESIC_CORE_QUERY_QUERY_SCRATCH_H_

#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <vector>

#include "core/base/bucket_queue.h"
#include "core/base/node_heap.h"
#include "core/dgg/dgg_graph.h"
#include "core/exact/exact_geodesic.h"
#include "core/mesh/mesh.h"
#include "core/query/graph_search.h"

namespace geodesic {

// Sources one field sweep serves at once (core/query/field_lanes.h): eight
// doubles, one cache line of labels per node.
inline constexpr int kFieldLanes = 8;
struct alignas(64) LaneLabels {
  double dist[kFieldLanes];
};
struct alignas(64) LaneFans {
  FanRange fan[kFieldLanes];
};
// The same fans in half the bytes, a fan's begin and count in 16 bits each,
// for graphs whose nodes all have fewer than 2^16 edges: so that a node's
// labels and fans both stay in a core's cache while a sweep works.
struct alignas(32) PackedLaneFans {
  uint32_t fan[kFieldLanes];
};
// Which of the two a sweep keeps (and a single field: fan or fan_packed
// below). kPacked only where LaneFanLayoutFor allows it; kWhole anywhere
// (tests choose it on small graphs too).
enum class LaneFanLayout { kPacked, kWhole };
// The smaller layout `g` allows: a scan of its nodes, made once per graph.
LaneFanLayout LaneFanLayoutFor(const DggGraph& g);

// The records of the nodes one point-to-point query touches, kept in the
// order they were first touched, and a per-node index into them. The index
// costs 4 bytes per graph node; the records (a cache line each) only what
// the query touches: a few thousand, where a record per graph node cost 64
// bytes per node. A query clears only the index entries it set.
class PairTable {
 public:
  struct alignas(64) Record {
    double dist[2];
    uint32_t pred[2];
    uint32_t slot[2];  // places in the two searches' heaps
    // The edges each search relaxes from the node (Field's fans). The
    // graph is symmetric, and so are its fans: u -> v -> w is a kept turn
    // exactly when w -> v -> u is, so the backward search uses them too.
    FanRange fan[2];
    // A* potential, computed on first touch. Its float rounding (~6e-8
    // relative) can only make an answer longer by as much, never shorter.
    float potential;
    uint32_t node;
    uint32_t settled;  // settled backward << 1 | settled forward
    bool done(int side) const { return settled >> side & 1; }
    void set_done(int side) { settled |= 1u << side; }
  };
  static_assert(sizeof(Record) == 64);

  // Starts a query on a graph of `nodes` nodes: no node is touched.
  void Reset(uint32_t nodes);
  // The record of `node`, or nullptr if this query has not touched it.
  Record* Find(uint32_t node) {
    const uint32_t i = index_[node];
    return i ? &records_[i - 1] : nullptr;
  }
  // The record of `node`, made (node set, the rest for the caller to fill)
  // if new. References to records stay valid until the next insert.
  Record& FindOrInsert(uint32_t node, bool* inserted) {
    uint32_t& i = index_[node];
    *inserted = i == 0;
    if (i == 0) {
      records_.emplace_back().node = node;
      records_.back().settled = 0;
      i = records_.size();
    }
    return records_[i - 1];
  }
  void Prefetch(uint32_t node) const { __builtin_prefetch(&index_[node]); }
  size_t touched() const { return records_.size(); }
  uint64_t bytes() const {
    return index_.capacity() * sizeof(uint32_t) + records_.capacity() * sizeof(Record);
  }

 private:
  std::vector<uint32_t> index_;  // per node: 1 + its record, 0 if untouched
  std::vector<Record> records_;
};

struct QueryScratch {
  // Field solves, which touch every node anyway and so size these to the
  // graph (on first use: a scratch that only answers pairs never does).
  std::vector<double> dist;
  // The edges a node relaxes once taken out: the fan of the edge that set
  // its label, copied from that edge's record when it improves the label;
  // packed in half the bytes where the graph allows (LaneFanLayoutFor).
  std::vector<FanRange> fan;
  std::vector<uint32_t> fan_packed;
  std::vector<uint32_t> label;  // index of the nearest source
  NodeHeap heap;                // Dijkstra's queue, for searches that stop at targets
  BucketQueue buckets;
  // Fields of several sources in one sweep (core/query/field_lanes.h): per
  // node, each lane's label and fan, and the lanes improved since the node
  // was last taken out.
  std::vector<LaneLabels> lane_dist;
  std::vector<LaneFans> lane_fan;  // or, for most graphs, these:
  std::vector<PackedLaneFans> lane_fan_packed;
  std::vector<uint8_t> lane_dirty;
  // When `lanes_clear_but_reached`, every node's lanes are +inf and clean
  // except those of the nodes listed in `lane_reached` (the nodes a bounded
  // sweep took out, duplicates and all): the next sweep resets only those, so
  // that a sweep near its sources costs what it reaches, not the graph.
  std::vector<uint32_t> lane_reached;
  bool lanes_clear_but_reached = false;

  PairTable pairs;
  // The forward (0) and backward (1) searches' queues, with their slots in
  // the records above.
  struct PairSlot {
    PairTable* table;
    int side;
    uint32_t& operator()(uint32_t node) const { return table->Find(node)->slot[side]; }
  };
  BasicNodeHeap<PairSlot> pair_heap[2] = {BasicNodeHeap<PairSlot>({&pairs, 0}),
                                          BasicNodeHeap<PairSlot>({&pairs, 1})};

  // Direct geodesics of points that are not graph nodes; made on first use.
  std::unique_ptr<ExactGeodesic> exact;
  // Face frames for `exact` to read instead of computing one per window:
  // the exact landmarks' (which live as long as the graph's engine), once
  // there are some. Set at each lease.
  const FaceFrames* frames = nullptr;

  // Sizes dist and the fans of `layout` to `nodes`, and label too when the
  // field `labels` its nearest sources (what a field does not use is left
  // out: memory a new process would fault in for nothing).
  void PrepareField(size_t nodes, bool labels, LaneFanLayout layout);
  void PrepareLanes(size_t nodes, LaneFanLayout layout);
  ExactGeodesic& Exact(const Mesh& mesh) {
    if (!exact) exact = std::make_unique<ExactGeodesic>(mesh);
    exact->set_frames(frames);
    return *exact;
  }
  // What this scratch holds, the exact engine's buffers included.
  uint64_t bytes() const;
};

// The scratch of one engine's queries in flight.
class ScratchPool {
 public:
  // `keep_idle`: scratches kept for later queries once released; beyond
  // them a released scratch is freed, so a burst of concurrent queries does
  // not pin its peak memory for good.
  explicit ScratchPool(int keep_idle) : keep_idle_(keep_idle) {}

  class Lease {
   public:
    Lease(ScratchPool* pool, std::unique_ptr<QueryScratch> scratch, uint64_t counted)
        : pool_(pool), scratch_(std::move(scratch)), counted_(counted) {}
    Lease(Lease&& other) noexcept
        : pool_(other.pool_), scratch_(std::move(other.scratch_)), counted_(other.counted_) {}
    Lease& operator=(Lease&&) = delete;
    ~Lease() {
      if (scratch_) pool_->Release(std::move(scratch_), counted_);
    }
    QueryScratch& operator*() const { return *scratch_; }
    QueryScratch* operator->() const { return scratch_.get(); }

   private:
    ScratchPool* pool_;
    std::unique_ptr<QueryScratch> scratch_;
    uint64_t counted_;  // its bytes as bytes() counts them
  };

  Lease Acquire();
  // Bytes held by idle scratches and by those in use, the latter at their
  // size when they were last released (they may have grown since).
  uint64_t bytes() const { return bytes_.load(std::memory_order_relaxed); }
  int in_use() const { return in_use_.load(std::memory_order_relaxed); }
  int idle() const;

 private:
  struct Idle {
    std::unique_ptr<QueryScratch> scratch;
    uint64_t bytes;
  };
  void Release(std::unique_ptr<QueryScratch> scratch, uint64_t counted);

  const int keep_idle_;
  // std::mutex, not absl::Mutex: Debian's Abseil is not built for
  // ThreadSanitizer, which then cannot see its locking, and every query
  // passes through here.
  mutable std::mutex mu_;
  std::vector<Idle> idle_;  // guarded by mu_
  std::atomic<uint64_t> bytes_{0};
  std::atomic<int> in_use_{0};
};

}  // namespace geodesic

#endif  // GEODESIC_CORE_QUERY_QUERY_SCRATCH_H_
