// The candidate edges of a graph build, as each source's propagation found
// them, held compactly until the build joins them into one adjacency.
//
// Every build thread appends whole source lists to a run of its own, in
// chunks. A sealed chunk stays in memory while the runs fit the memory budget
// and goes to an unlinked file beside the output beyond it, so a build's
// candidate phase holds at most the budget whatever the mesh. The runs are
// read back once, in a stream, each chunk released as soon as it is read.
#ifndef GEODESIC_CORE_DGG_CANDIDATE_RUNS_H_
#define GEODESIC_CORE_DGG_CANDIDATE_RUNS_H_

#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <span>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "core/base/large_array.h"
#include "core/dgg/dgg_graph.h"
#include "tbb/enumerable_thread_specific.h"

namespace geodesic {

class CandidateRuns {
 public:
  // memory_budget: bytes of sealed chunks kept in memory (0: no limit).
  // spill_dir: where the unlinked spill file goes once the budget is spent.
  // admit_spill: asked, if set, before the spill file grows to `bytes` in
  // all, and with 0 once it is gone (DggBuildOptions::admit_spill).
  using AdmitSpill = std::function<absl::Status(uint64_t bytes)>;
  CandidateRuns(uint32_t num_vertices, uint64_t memory_budget, std::string spill_dir,
                AdmitSpill admit_spill = {});
  ~CandidateRuns();
  CandidateRuns(const CandidateRuns&) = delete;
  CandidateRuns& operator=(const CandidateRuns&) = delete;

  // Appends the list of `source` (each source once). Safe to call from many
  // threads at once. Fails only when spilling to disk fails.
  absl::Status Add(uint32_t source, std::span<const DggHalfEdge> edges);

  // After every Add: the length of each source's list.
  const std::vector<uint32_t>& counts() const { return counts_; }
  uint64_t spilled_bytes() const { return spilled_bytes_; }

  // Calls visit(source, edges) once for every list added, in no particular
  // order and from as many threads as the calling arena has (so `visit` must
  // be safe to run for different sources at once), and releases the runs as
  // it goes. Call once, from one thread, after every Add has returned.
  using Visitor = std::function<void(uint32_t source, std::span<const DggHalfEdge> edges)>;
  absl::Status Drain(const Visitor& visit);

 private:
  struct Chunk {
    LargeArray<std::byte> bytes;
    size_t used = 0;
  };
  struct Spilled {
    uint64_t offset, bytes;
  };
  // Visits the chunk's records in parallel, on as many threads as the
  // caller's arena has.
  static void VisitChunk(const std::byte* data, size_t bytes, const Visitor& visit);
  absl::Status Seal(std::unique_ptr<Chunk> chunk);  // takes the lock
  absl::Status OpenSpillFile();                     // with the lock held
  void CloseSpillFile();

  const uint64_t memory_budget_;
  const size_t chunk_bytes_;
  const std::string spill_dir_;
  const AdmitSpill admit_spill_;
  std::vector<uint32_t> counts_;

  tbb::enumerable_thread_specific<std::unique_ptr<Chunk>> open_;  // one per thread

  std::mutex mu_;                               // guards what follows
  std::vector<std::unique_ptr<Chunk>> sealed_;  // in memory
  uint64_t sealed_bytes_ = 0;
  std::vector<Spilled> spilled_;
  uint64_t spilled_bytes_ = 0;
  int spill_fd_ = -1;
  std::string spill_path_;  // for messages
};

}  // namespace geodesic

#endif  // GEODESIC_CORE_DGG_CANDIDATE_RUNS_H_
