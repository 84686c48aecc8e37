// Memory the HTTP gateway holds outside any query, counted against
// --memory-limit: request bodies while they are read and parsed, and large
// answers while they are serialised and written. A reservation is taken
// before the bytes are, and refused, naming the limit, when they cannot fit
// beside what the limit already holds; the service's admission and the
// graph cache count what is reserved as memory in use.
#ifndef GEODESIC_SERVER_MEMORY_LEDGER_H_
#define GEODESIC_SERVER_MEMORY_LEDGER_H_

#include <cstdint>
#include <functional>
#include <memory>
#include <string>

#include "absl/base/thread_annotations.h"
#include "absl/status/statusor.h"
#include "absl/synchronization/mutex.h"

namespace geodesic::server {

class MemoryLedger {
 public:
  // `limit`: --memory-limit (0: nothing is reserved or refused). `in_use`:
  // the bytes a reservation must fit beside (registered meshes, the running
  // queries' reservations).
  MemoryLedger(uint64_t limit, std::function<uint64_t()> in_use)
      : limit_(limit), in_use_(std::move(in_use)) {}

  // `bytes` of the limit for `what`, given back when the last copy of the
  // result is dropped (null without a limit). RESOURCE_EXHAUSTED when they
  // could never fit beside what is in use; UNAVAILABLE when they do not
  // fit now, beside other reservations.
  absl::StatusOr<std::shared_ptr<void>> Reserve(uint64_t bytes, const std::string& what);

  uint64_t reserved() const;
  uint64_t limit() const { return limit_; }

 private:
  void Release(uint64_t bytes);

  const uint64_t limit_;
  const std::function<uint64_t()> in_use_;
  mutable absl::Mutex mu_;
  uint64_t reserved_ ABSL_GUARDED_BY(mu_) = 0;
};

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_MEMORY_LEDGER_H_
