#include "core/base/radix_heap.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <random>
#include <set>
#include <vector>

#include "gtest/gtest.h"
#include "tests/core/radix_heap_workload.h"

namespace geodesic {
namespace {

// A wavefront-like workload: each pop pushes a few keys at or beyond the
// popped one. The heap must pop exactly the multiset a sorted reference does.
TEST(RadixHeapTest, PopsMonotoneWorkloadInKeyOrder) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> step(0.0, 3.0);
  std::uniform_int_distribution<int> fanout(0, 3);
  RadixHeap<uint32_t> heap;
  std::multimap<double, uint32_t> reference;
  uint32_t next_id = 0;
  for (int i = 0; i < 8; ++i) {
    const double key = step(rng);
    heap.Push(key, next_id);
    reference.emplace(key, next_id++);
  }
  size_t popped = 0;
  double last = 0;
  while (!heap.empty()) {
    ASSERT_EQ(heap.size(), reference.size());
    const auto [key, id] = heap.Pop();
    ASSERT_GE(key, last);
    // Ties may pop in any order: find this id among the smallest keys.
    auto smallest = reference.begin();
    ASSERT_EQ(key, smallest->first);
    auto [lo, hi] = reference.equal_range(key);
    // By value: clang before 16 cannot capture a structured binding.
    auto it = std::find_if(lo, hi, [popped = id](const auto& kv) { return kv.second == popped; });
    ASSERT_NE(it, hi) << "popped id " << id << " with key " << key;
    reference.erase(it);
    last = key;
    if (++popped < 20000) {
      for (int k = fanout(rng); k > 0; --k) {
        const double child = key + (k == 1 ? 0.0 : step(rng));  // equal keys too
        heap.Push(child, next_id);
        reference.emplace(child, next_id++);
      }
    }
  }
  EXPECT_TRUE(reference.empty());
  EXPECT_GT(popped, 1000u);
}

// PeekNext, when it answers, names the value the next Pop returns (keys are
// distinct here, so that value is unique), and it answers often enough to be
// worth asking. PeekKey always names the key.
TEST(RadixHeapTest, PeekNextIsWhatPopReturnsNext) {
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> step(0.0, 3.0);
  RadixHeap<uint32_t> heap;
  uint32_t next_id = 0;
  for (int i = 0; i < 64; ++i) heap.Push(step(rng), next_id++);
  size_t answered = 0, popped = 0;
  while (!heap.empty()) {
    const uint32_t* peeked = heap.PeekNext();
    const uint32_t expected = peeked ? *peeked : 0;
    const double least = heap.PeekKey();
    const auto [key, id] = heap.Pop();
    ASSERT_EQ(key, least);
    if (peeked) {
      ++answered;
      ASSERT_EQ(id, expected) << "after " << popped << " pops";
    }
    if (++popped < 5000) {
      for (int k = 0; k < 2; ++k) heap.Push(key + step(rng), next_id++);
    }
  }
  EXPECT_GT(popped, 5000u);
  EXPECT_GT(answered, popped / 4);
}

TEST(RadixHeapTest, RaisesKeysBelowTheLastPoppedOne) {
  RadixHeap<int> heap;
  heap.Push(2.0, 1);
  heap.Push(5.0, 2);
  EXPECT_EQ(heap.Pop(), std::make_pair(2.0, 1));
  // A key a rounding error below the last popped one keeps the order.
  heap.Push(std::nextafter(2.0, 0.0), 3);
  EXPECT_EQ(heap.Pop(), std::make_pair(2.0, 3));
  EXPECT_EQ(heap.Pop(), std::make_pair(5.0, 2));
  EXPECT_TRUE(heap.empty());
}

// A small bucket becomes a sorted run that pops from its end; keys pushed
// among the run's keys must come out in order with them, and keys beyond it
// after it.
TEST(RadixHeapTest, PushesAmongASortedRunPopInOrder) {
  RadixHeap<int> heap;
  for (int k = 2; k <= 10; ++k) heap.Push(k, k);
  heap.Push(1.0, 1);
  EXPECT_EQ(heap.Pop(), std::make_pair(1.0, 1));
  EXPECT_EQ(heap.Pop(), std::make_pair(2.0, 2));  // 3..10 wait in the run
  heap.Push(9.5, 95);
  heap.Push(20.0, 200);
  heap.Push(3.5, 35);
  heap.Push(5.0, 50);
  heap.Push(10.0, 100);
  std::vector<double> keys;
  while (!heap.empty()) keys.push_back(heap.Pop().first);
  EXPECT_EQ(keys, (std::vector<double>{3, 3.5, 4, 5, 5, 6, 7, 8, 9, 9.5, 10, 10, 20}));
}

// Each pop pushes two distinct keys just above the popped one, below the
// run's largest: nearly every push lands inside the run. Unbounded, the run
// would grow by one entry per pop and each insert would move all of it; it
// stays within its bound, and keys still pop in order.
TEST(RadixHeapTest, PushesThatAllLandInTheRunKeepItBounded) {
  RadixHeap<uint32_t> heap;
  std::multiset<double> reference;
  auto pushed = [&](double key) { reference.insert(key); };
  testing::FillOneBucket(heap, pushed);
  size_t longest = 0;
  int64_t pops = 0;
  testing::PushIntoTheRun(
      heap, 20000,
      [&](int64_t step, double key) {
        if (key != *reference.begin()) {
          ADD_FAILURE() << "at step " << step << " popped " << key << ", not "
                        << *reference.begin();
          return false;
        }
        reference.erase(reference.begin());
        longest = std::max(longest, heap.run_size());
        ++pops;
        return true;
      },
      pushed);
  EXPECT_EQ(pops, 20000);
  EXPECT_GT(longest, RadixHeap<uint32_t>::kSortedRun);
  EXPECT_LE(longest, RadixHeap<uint32_t>::kLongestRun);
  std::vector<double> rest;
  while (!heap.empty()) rest.push_back(heap.Pop().first);
  EXPECT_TRUE(std::equal(rest.begin(), rest.end(), reference.begin(), reference.end()));
}

TEST(RadixHeapTest, InfinityNanAndZeroKeys) {
  const double inf = std::numeric_limits<double>::infinity();
  RadixHeap<int> heap;
  heap.Push(std::numeric_limits<double>::quiet_NaN(), 1);
  heap.Push(inf, 2);
  heap.Push(-0.0, 3);
  heap.Push(1e-300, 4);
  EXPECT_EQ(heap.Pop(), std::make_pair(0.0, 3));
  EXPECT_EQ(heap.Pop(), std::make_pair(1e-300, 4));
  EXPECT_EQ(heap.Pop().first, inf);
  EXPECT_EQ(heap.Pop().first, inf);
  EXPECT_TRUE(heap.empty());
  heap.Push(3.0, 5);
  heap.Clear();
  EXPECT_TRUE(heap.empty());
  heap.Push(1.0, 6);  // after Clear, keys start again from zero
  EXPECT_EQ(heap.Pop(), std::make_pair(1.0, 6));
}

}  // namespace
}  // namespace geodesic
