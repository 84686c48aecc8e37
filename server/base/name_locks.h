// One lock per name, for as many names as there are: the service holds a
// mesh's name while it changes that mesh (register, upload, unload, graph
// requests and cancels), so the registry, the graph cache and the catalog
// see one name's changes in one order. Interleaved, a registration and an
// unload of one name could leave the catalog listing a mesh the registry
// had dropped: told "registered", a client then got "not found".
#ifndef GEODESIC_SERVER_NAME_LOCKS_H_
#define GEODESIC_SERVER_NAME_LOCKS_H_

#include <string>

#include "absl/base/thread_annotations.h"
#include "absl/container/flat_hash_set.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"

namespace geodesic::server {

class NameLocks {
 public:
  // Holds `name` from construction (waiting while another holder has it,
  // until `deadline`) to destruction. Other names are not held up.
  class Hold {
   public:
    Hold(NameLocks& locks, std::string name, absl::Time deadline = absl::InfiniteFuture())
        : locks_(locks), name_(std::move(name)) {
      absl::MutexLock lock(&locks_.mu_);
      held_ = locks_.mu_.AwaitWithDeadline(absl::Condition(this, &Hold::Free), deadline);
      if (held_) locks_.held_.insert(name_);
    }
    ~Hold() {
      if (!held_) return;
      absl::MutexLock lock(&locks_.mu_);
      locks_.held_.erase(name_);
    }
    Hold(const Hold&) = delete;
    Hold& operator=(const Hold&) = delete;

    // False if the deadline passed first: the caller holds nothing.
    bool held() const { return held_; }

   private:
    bool Free() const ABSL_EXCLUSIVE_LOCKS_REQUIRED(locks_.mu_) {
      return !locks_.held_.contains(name_);
    }

    NameLocks& locks_;
    const std::string name_;
    bool held_ = false;
  };

 private:
  absl::Mutex mu_;
  absl::flat_hash_set<std::string> held_ ABSL_GUARDED_BY(mu_);
};

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_NAME_LOCKS_H_
