// The build lock replicas sharing --graph-dir take so that one of them
// builds each graph (ReplicaLock), and the cache's calls on those locks:
// their path, and the sweep of locks builders killed mid-build left.
#include "server/graphs/replica_lock.h"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <filesystem>
#include <utility>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "core/base/atomic_file.h"
#include "server/graphs/graph_cache.h"

namespace geodesic::server {

absl::StatusOr<ReplicaLock> ReplicaLock::TryAcquire(const std::string& path) {
  for (int attempt = 0; attempt < 8; ++attempt) {
    const int fd = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
    if (fd < 0) return ErrnoStatus("cannot open lock file", path);
    if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
      const bool busy = errno == EWOULDBLOCK;
      absl::Status s = ErrnoStatus("cannot lock", path);
      ::close(fd);
      if (busy) return ReplicaLock();
      return s;
    }
    struct stat held, named;
    if (::fstat(fd, &held) == 0 && ::stat(path.c_str(), &named) == 0 &&
        held.st_dev == named.st_dev && held.st_ino == named.st_ino) {
      ReplicaLock lock;
      lock.path_ = path;
      lock.fd_ = fd;
      return lock;
    }
    ::close(fd);  // a holder unlinked it while we locked it
  }
  return absl::AbortedError(absl::StrFormat("%s keeps being replaced", path));
}

void ReplicaLock::Release() {
  if (fd_ < 0) return;
  ::unlink(path_.c_str());
  ::close(std::exchange(fd_, -1));
}

// Hidden, as the catalog's reserve: bookkeeping, not a graph.
std::string BuildLockPath(const std::string& graph_path) {
  const std::filesystem::path p(graph_path);
  return (p.parent_path() / ("." + p.filename().string() + ".lock")).string();
}

std::string GraphCache::BuildLockFile(const std::string& graph_path) {
  return BuildLockPath(graph_path);
}

std::vector<std::string> GraphCache::RemoveStaleBuildLocks(const std::string& dir,
                                                           std::chrono::seconds min_age) {
  std::vector<std::string> removed;
  ForEachFileOlderThan(dir, min_age, [&](const std::string& name, const auto& path) {
    if (!name.starts_with(".") || !name.ends_with(".dgg.lock")) return;
    // Only a lock nobody holds: its builder died. Taking it and letting it
    // go unlinks it.
    auto lock = ReplicaLock::TryAcquire(path.string());
    if (lock.ok() && lock->held()) {
      lock->Release();
      removed.push_back(name);
    }
  });
  return removed;
}

}  // namespace geodesic::server
