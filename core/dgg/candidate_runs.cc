#include "core/dgg/candidate_runs.h"

#include <fcntl.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <vector>

#include "absl/strings/str_format.h"
#include "core/base/atomic_file.h"
#include "core/base/status.h"
#include "core/base/thread_arena.h"

namespace geodesic {
namespace {

// Chunks are mapped this large and committed as they fill: big enough that
// sealing (and spilling) is rare, small enough that the chunks each thread
// has open cost little beside the runs, and well inside a budget.
size_t ChunkBytes(uint64_t memory_budget) {
  constexpr uint64_t kMin = uint64_t{1} << 20, kMax = uint64_t{64} << 20;
  return memory_budget == 0 ? kMax : std::clamp(memory_budget / 16, kMin, kMax);
}

struct RecordHeader {
  uint32_t source;
  uint32_t count;
};
static_assert(sizeof(RecordHeader) % alignof(DggHalfEdge) == 0);

size_t RecordBytes(size_t count) { return sizeof(RecordHeader) + count * sizeof(DggHalfEdge); }

}  // namespace

CandidateRuns::CandidateRuns(uint32_t num_vertices, uint64_t memory_budget, std::string spill_dir,
                             AdmitSpill admit_spill)
    : memory_budget_(memory_budget),
      chunk_bytes_(ChunkBytes(memory_budget)),
      spill_dir_(std::move(spill_dir)),
      admit_spill_(std::move(admit_spill)),
      counts_(num_vertices, 0) {}

CandidateRuns::~CandidateRuns() { CloseSpillFile(); }

absl::Status CandidateRuns::Add(uint32_t source, std::span<const DggHalfEdge> edges) {
  counts_[source] = edges.size();
  const size_t bytes = RecordBytes(edges.size());
  std::unique_ptr<Chunk>& chunk = open_.local();
  if (chunk && chunk->used + bytes > chunk->bytes.size()) {
    RETURN_IF_ERROR(Seal(std::move(chunk)));
  }
  if (!chunk) {
    chunk = std::make_unique<Chunk>();
    chunk->bytes.resize(std::max(chunk_bytes_, bytes));
  }
  std::byte* at = chunk->bytes.data() + chunk->used;
  const RecordHeader header{source, static_cast<uint32_t>(edges.size())};
  std::memcpy(at, &header, sizeof(header));
  if (!edges.empty()) std::memcpy(at + sizeof(header), edges.data(), edges.size_bytes());
  chunk->used += bytes;
  return absl::OkStatus();
}

absl::Status CandidateRuns::Seal(std::unique_ptr<Chunk> chunk) {
  std::lock_guard<std::mutex> lock(mu_);
  if (memory_budget_ == 0 || sealed_bytes_ + chunk->used <= memory_budget_) {
    sealed_bytes_ += chunk->used;
    sealed_.push_back(std::move(chunk));
    return absl::OkStatus();
  }
  // Admitted before the file grows, so that a disk budget is never passed,
  // not even for the moments the spill lasts.
  if (admit_spill_) RETURN_IF_ERROR(admit_spill_(spilled_bytes_ + chunk->used));
  if (spill_fd_ < 0) RETURN_IF_ERROR(OpenSpillFile());
  const std::byte* data = chunk->bytes.data();
  for (size_t done = 0; done < chunk->used;) {
    const ssize_t n = ::pwrite(spill_fd_, data + done, chunk->used - done, spilled_bytes_ + done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return ErrnoStatus("cannot spill candidate edges to", spill_path_);
    done += n;
  }
  spilled_.push_back({spilled_bytes_, chunk->used});
  spilled_bytes_ += chunk->used;
  return absl::OkStatus();
}

absl::Status CandidateRuns::OpenSpillFile() {
  const std::string dir = spill_dir_.empty() ? "." : spill_dir_;
  spill_path_ = dir + " (unlinked spill file)";
  // O_TMPFILE: no name, so nothing is left behind by a crash.
  spill_fd_ = ::open(dir.c_str(), O_TMPFILE | O_RDWR | O_CLOEXEC, 0600);
  if (spill_fd_ >= 0) return absl::OkStatus();
  std::string path = dir + "/geodesicd-candidates-XXXXXX";
  spill_fd_ = ::mkstemp(path.data());
  if (spill_fd_ < 0) return ErrnoStatus("cannot create a spill file in", dir);
  ::unlink(path.c_str());
  return absl::OkStatus();
}

void CandidateRuns::CloseSpillFile() {
  if (spill_fd_ < 0) return;
  ::close(spill_fd_);  // unlinked: its blocks go with the descriptor
  spill_fd_ = -1;
  if (admit_spill_) admit_spill_(0).IgnoreError();
}

void CandidateRuns::VisitChunk(const std::byte* data, size_t bytes, const Visitor& visit) {
  // Records have their own lengths: find where each starts (a walk over the
  // headers only), then copy them out in parallel. Copied one after another,
  // they were a serial step that held two-thread builds back from scaling
  // (BENCHMARKS.md, "Graph construction", the 2t speed-up column).
  std::vector<size_t> starts;
  for (size_t at = 0; at < bytes;) {
    RecordHeader header;
    std::memcpy(&header, data + at, sizeof(header));
    starts.push_back(at);
    at += RecordBytes(header.count);
  }
  // An arena of the caller's width, not the caller's arena itself: a caller
  // outside any arena then still gets ThreadArena's one thread under TSan.
  ThreadArena arena(tbb::this_task_arena::max_concurrency());
  arena.execute([&] {
    tbb::parallel_for(
        tbb::blocked_range<size_t>(0, starts.size(), 64), [&](const tbb::blocked_range<size_t>& r) {
          for (size_t i = r.begin(); i != r.end(); ++i) {
            RecordHeader header;
            std::memcpy(&header, data + starts[i], sizeof(header));
            const auto* edges =
                reinterpret_cast<const DggHalfEdge*>(data + starts[i] + sizeof(header));
            visit(header.source, {edges, header.count});
          }
        });
  });
}

absl::Status CandidateRuns::Drain(const Visitor& visit) {
  for (std::unique_ptr<Chunk>& chunk : open_) {
    if (chunk) VisitChunk(chunk->bytes.data(), chunk->used, visit);
    chunk.reset();
  }
  open_.clear();
  for (std::unique_ptr<Chunk>& chunk : sealed_) {
    VisitChunk(chunk->bytes.data(), chunk->used, visit);
    chunk.reset();
  }
  sealed_.clear();
  sealed_bytes_ = 0;
  LargeArray<std::byte> buffer;
  for (const Spilled& s : spilled_) {
    buffer.resize(s.bytes);
    for (size_t done = 0; done < s.bytes;) {
      const ssize_t n = ::pread(spill_fd_, buffer.data() + done, s.bytes - done, s.offset + done);
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) return ErrnoStatus("cannot read back candidate edges from", spill_path_);
      done += n;
    }
    VisitChunk(buffer.data(), s.bytes, visit);
  }
  spilled_.clear();
  CloseSpillFile();
  return absl::OkStatus();
}

}  // namespace geodesic
