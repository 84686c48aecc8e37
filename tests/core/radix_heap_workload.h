// The radix heap's worst case for its sorted run, shared by its unit test
// (which checks the order and the run's bound) and its microbenchmark (which
// times it): 64 keys in [1, 2), one bucket the first pop sorts into the run,
// then each pop pushes two distinct keys just above the popped one, below the
// run's largest, so that nearly every push lands inside the run.
#ifndef GEODESIC_TESTS_CORE_RADIX_HEAP_WORKLOAD_H_
#define GEODESIC_TESTS_CORE_RADIX_HEAP_WORKLOAD_H_

#include <cstdint>
#include <random>

namespace geodesic::testing {

// Fills `heap` with the 64 first keys; `pushed(key)` sees each.
template <typename Heap, typename Pushed>
void FillOneBucket(Heap& heap, Pushed pushed) {
  for (int k = 0; k < 64; ++k) {
    heap.Push(1 + k / 64.0, k);
    pushed(1 + k / 64.0);
  }
}

// Pops `pops` times, pushing two keys just above each popped one;
// `popped(step, key)` sees each pop (false stops the run) and `pushed(key)`
// each push.
template <typename Heap, typename Popped, typename Pushed>
void PushIntoTheRun(Heap& heap, int64_t pops, Popped popped, Pushed pushed) {
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> tiny(1e-9, 2e-9);
  for (int64_t step = 0; step < pops; ++step) {
    const double key = heap.Pop().first;
    if (!popped(step, key)) return;
    for (double above : {key + tiny(rng), key + tiny(rng)}) {
      heap.Push(above, static_cast<uint32_t>(step));
      pushed(above);
    }
  }
}

}  // namespace geodesic::testing

#endif  // GEODESIC_TESTS_CORE_RADIX_HEAP_WORKLOAD_H_
