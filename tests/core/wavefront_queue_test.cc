#include "core/base/wavefront_queue.h"

#include <cmath>
#include <cstdint>
#include <limits>
#include <map>
#include <random>
#include <vector>

#include "gtest/gtest.h"

namespace geodesic {
namespace {

// Items carry their key and whether they were pushed in exact order.
struct Item {
  double key;
  bool exact;
  uint32_t id;
};

// A propagation-like workload: each pop pushes a few items at or beyond the
// key it popped, loose and exact mixed, some far ahead (past the ring), some
// below the lowest bucket. Every item must come out once; the key Pop
// returns must be at most every key still queued (so that a caller can tell
// what is settled); and an exact item must leave only after every item with a
// smaller key, which is what lets a vertex radiate from a final distance.
void RunWorkload(double width, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> step(0.0, 3.0);
  std::uniform_int_distribution<int> fanout(0, 3);
  std::uniform_int_distribution<int> kind(0, 9);
  WavefrontQueue<Item> queue;
  queue.Reset(width);
  std::multimap<double, uint32_t> queued;  // key -> id
  uint32_t next_id = 0;
  auto push = [&](double key, bool exact) {
    const Item item{key, exact, next_id++};
    exact ? queue.PushExact(key, item) : queue.PushLoose(key, item);
    queued.emplace(key, item.id);
  };
  for (int i = 0; i < 8; ++i) push(step(rng), false);
  size_t popped = 0, exact_popped = 0;
  while (!queue.empty()) {
    ASSERT_EQ(queue.size(), queued.size());
    const auto [floor, item] = queue.Pop();
    ASSERT_LE(floor, queued.begin()->first) << "after " << popped << " pops";
    ASSERT_LE(floor, item.key);
    if (item.exact) {
      ++exact_popped;
      ASSERT_EQ(item.key, queued.begin()->first) << "an exact item left before a nearer one";
      ASSERT_EQ(floor, item.key);
    }
    auto [lo, hi] = queued.equal_range(item.key);
    auto it = lo;
    while (it != hi && it->second != item.id) ++it;
    ASSERT_NE(it, hi) << "item " << item.id << " came out twice or was never queued";
    queued.erase(it);
    if (++popped < 20000) {
      for (int k = fanout(rng); k > 0; --k) {
        const int what = kind(rng);
        if (what == 0) {
          push(item.key + 1000 * width * step(rng), false);  // past the ring
        } else if (what <= 2) {
          push(item.key + step(rng), true);
        } else {
          push(item.key + (what == 3 ? 0.0 : step(rng)), false);
        }
      }
    }
  }
  EXPECT_TRUE(queued.empty());
  EXPECT_GT(popped, 20000u);
  EXPECT_GT(exact_popped, 1000u);
}

TEST(WavefrontQueueTest, ExactItemsWaitForEveryNearerItem) {
  for (double width : {0.05, 0.5, 4.0}) {
    SCOPED_TRACE(width);
    RunWorkload(width, 7);
  }
}

// Without a usable width every item is exact: pops come out in key order.
TEST(WavefrontQueueTest, WithoutAWidthEveryItemIsInKeyOrder) {
  for (double width : {0.0, -1.0, std::numeric_limits<double>::infinity(), std::nan("")}) {
    WavefrontQueue<int> queue;
    queue.Reset(width);
    queue.PushLoose(3.0, 3);
    queue.PushLoose(1.0, 1);
    queue.PushLoose(2.0, 2);
    EXPECT_EQ(queue.Pop(), std::make_pair(1.0, 1));
    EXPECT_EQ(queue.Pop(), std::make_pair(2.0, 2));
    EXPECT_EQ(queue.Pop(), std::make_pair(3.0, 3));
    EXPECT_TRUE(queue.empty());
  }
}

// Loose items of one bucket leave last in, first out (the children of the
// window just propagated, whose face is still in cache); a NaN or infinite
// key waits in the heap and leaves last.
TEST(WavefrontQueueTest, OneBucketIsLastInFirstOutAndOddKeysComeLast) {
  WavefrontQueue<int> queue;
  queue.Reset(1.0);
  queue.PushLoose(std::numeric_limits<double>::infinity(), 9);
  queue.PushLoose(std::nan(""), 8);
  queue.PushLoose(0.2, 1);
  queue.PushLoose(0.7, 2);
  queue.PushLoose(0.5, 3);
  EXPECT_EQ(queue.Pop(), std::make_pair(0.0, 3));
  EXPECT_EQ(queue.Pop(), std::make_pair(0.0, 2));
  EXPECT_EQ(queue.Pop(), std::make_pair(0.0, 1));
  EXPECT_EQ(queue.Pop().first, std::numeric_limits<double>::infinity());
  EXPECT_EQ(queue.Pop().first, std::numeric_limits<double>::infinity());
  EXPECT_TRUE(queue.empty());
}

}  // namespace
}  // namespace geodesic
