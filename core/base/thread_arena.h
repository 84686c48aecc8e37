// The TBB arena a parallel job of the core (a build, an accuracy check) runs
// in, with the job's thread count.
#ifndef GEODESIC_CORE_BASE_THREAD_ARENA_H_
#define GEODESIC_CORE_BASE_THREAD_ARENA_H_

#include <tbb/global_control.h>
#include <tbb/info.h>
#include <tbb/task_arena.h>

#include <utility>

namespace geodesic {

// Debian's libtbb is not built with TSan, which then cannot see how TBB
// hands split ranges between its threads and reports that bookkeeping as
// races; TSan builds (GEODESIC_TSAN) therefore keep TBB to the calling
// thread, and what TSan checks is the concurrency written here (queries and
// landmarks on shared graphs).
class ThreadArena {
 public:
  // threads <= 0: every core.
  explicit ThreadArena([[maybe_unused]] int threads)
#ifdef GEODESIC_TSAN
      : one_thread_(tbb::global_control::max_allowed_parallelism, 1),
        arena_(1)
#else
      : arena_(threads > 0 ? threads : tbb::info::default_concurrency())
#endif
  {
  }
  template <typename F>
  void execute(F&& f) {
    arena_.execute(std::forward<F>(f));
  }

 private:
#ifdef GEODESIC_TSAN
  tbb::global_control one_thread_;
#endif
  tbb::task_arena arena_;
};

}  // namespace geodesic

#endif  // GEODESIC_CORE_BASE_THREAD_ARENA_H_
