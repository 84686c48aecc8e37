#include "server/limits/memory_ledger.h"

#if defined(__GLIBC__)
#include <malloc.h>
#endif

#include "absl/strings/str_format.h"

namespace geodesic::server {
namespace {

// A reservation this large held memory made and freed in bulk: a request
// body's JSON tree and what was copied from it, an upload's bytes. glibc
// keeps freed pages resident while a small block allocated later sits above
// them in their heap (measured: up to a second after the answer was sent), so
// the next reservation's bytes would be made in fresh pages beside them, past
// the limit. They are handed back to the system before the ledger gives the
// bytes back.
constexpr uint64_t kTrimAtBytes = uint64_t{16} << 20;

}  // namespace

absl::StatusOr<std::shared_ptr<void>> MemoryLedger::Reserve(uint64_t bytes,
                                                            const std::string& what) {
  if (limit_ == 0) return std::shared_ptr<void>();
  const uint64_t in_use = in_use_ ? in_use_() : 0;
  {
    absl::MutexLock lock(&mu_);
    if (in_use + reserved_ + bytes <= limit_) {
      reserved_ += bytes;
      // The deleter owns nothing: it only gives the bytes back.
      return std::shared_ptr<void>(nullptr, [this, bytes](void*) { Release(bytes); });
    }
  }
  if (in_use + bytes > limit_) {
    return absl::ResourceExhaustedError(absl::StrFormat(
        "%s needs %u bytes, more than the %u bytes of the server's memory limit (--memory-limit, "
        "%u bytes) left beside the registered meshes and running queries",
        what, bytes, in_use < limit_ ? limit_ - in_use : 0, limit_));
  }
  return absl::UnavailableError(absl::StrFormat(
      "%s needs %u bytes of the server's memory limit (--memory-limit, %u bytes), which other "
      "requests hold now: retry",
      what, bytes, limit_));
}

void MemoryLedger::Release(uint64_t bytes) {
#if defined(__GLIBC__)
  if (bytes >= kTrimAtBytes) malloc_trim(0);
#endif
  absl::MutexLock lock(&mu_);
  reserved_ -= bytes;
}

uint64_t MemoryLedger::reserved() const {
  absl::MutexLock lock(&mu_);
  return reserved_;
}

}  // namespace geodesic::server
