// The lock that makes replicas sharing --graph-dir build each graph once
// (graph_cache.h, "Replicas sharing --graph-dir"): a file lock, so the
// kernel lets go of it when its holder dies, and a replica waiting for it
// builds the graph itself.
#ifndef GEODESIC_SERVER_REPLICA_LOCK_H_
#define GEODESIC_SERVER_REPLICA_LOCK_H_

#include <string>
#include <utility>

#include "absl/status/statusor.h"

namespace geodesic::server {

// An exclusive flock on a graph's ".<file>.lock", so that of the replicas
// sharing --graph-dir one builds the graph. The holder unlinks the file
// before it lets go, so nothing stays behind; a replica that locked the
// unlinked file meanwhile sees that the path names another file (or none)
// and tries again on the one there now.
class ReplicaLock {
 public:
  ReplicaLock() = default;
  ReplicaLock(ReplicaLock&& other) noexcept
      : path_(std::move(other.path_)), fd_(std::exchange(other.fd_, -1)) {}
  ReplicaLock& operator=(ReplicaLock&& other) noexcept {
    Release();
    path_ = std::move(other.path_);
    fd_ = std::exchange(other.fd_, -1);
    return *this;
  }
  ~ReplicaLock() { Release(); }

  // Held, not held (another process holds it), or an error (a directory
  // that refuses the file: the build goes on unlocked).
  static absl::StatusOr<ReplicaLock> TryAcquire(const std::string& path);
  bool held() const { return fd_ >= 0; }
  void Release();

 private:
  std::string path_;
  int fd_ = -1;
};

// The lock file of the graph file `graph_path`: ".<file>.lock" beside it.
std::string BuildLockPath(const std::string& graph_path);

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_REPLICA_LOCK_H_
