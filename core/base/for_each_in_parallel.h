// Runs independent pieces of one request (a pair, a matrix row) on TBB's
// workers.
#ifndef GEODESIC_CORE_BASE_FOR_EACH_IN_PARALLEL_H_
#define GEODESIC_CORE_BASE_FOR_EACH_IN_PARALLEL_H_

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <atomic>
#include <cstddef>
#include <functional>
#include <vector>

#include "absl/status/status.h"

namespace geodesic {

// Runs body(0), ..., body(n - 1) on TBB's workers, one index per task (a
// pair or a row is milliseconds of work, so finer grains only add
// overhead). Returns the error of the lowest failing index, so that a
// request's error does not depend on scheduling.
inline absl::Status ForEachInParallel(size_t n, const std::function<absl::Status(size_t)>& body) {
  std::vector<absl::Status> errors(n);
  std::atomic<bool> failed{false};
  auto run = [&](size_t i) {
    errors[i] = body(i);
    if (!errors[i].ok()) failed = true;
  };
#ifdef GEODESIC_TSAN
  // TSan cannot see TBB's synchronisation (core/base/thread_arena.h): in order.
  for (size_t i = 0; i < n; ++i) run(i);
#else
  tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 1), [&](const tbb::blocked_range<size_t>& r) {
    for (size_t i = r.begin(); i != r.end(); ++i) run(i);
  });
#endif
  if (failed) {
    for (absl::Status& e : errors) {
      if (!e.ok()) return e;
    }
  }
  return absl::OkStatus();
}

}  // namespace geodesic

#endif  // GEODESIC_CORE_BASE_FOR_EACH_IN_PARALLEL_H_
