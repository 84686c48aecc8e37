// One name's holders take turns; other names are not held up.
#include "server/base/name_locks.h"

#include <atomic>
#include <chrono>
#include <future>
#include <thread>
#include <vector>

#include "gtest/gtest.h"

namespace geodesic::server {
namespace {

TEST(NameLocksTest, HoldersOfOneNameTakeTurns) {
  NameLocks locks;
  std::atomic<int> inside{0}, most{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&] {
      for (int i = 0; i < 200; ++i) {
        NameLocks::Hold hold(locks, "mesh");
        const int now = ++inside;
        int seen = most.load();
        while (now > seen && !most.compare_exchange_weak(seen, now)) {
        }
        std::this_thread::yield();
        --inside;
      }
    });
  }
  for (auto& t : threads) t.join();
  EXPECT_EQ(most.load(), 1);
}

TEST(NameLocksTest, AnotherNameIsNotHeldUpAndTheNameIsFreedOnRelease) {
  NameLocks locks;
  auto hold_a = std::make_unique<NameLocks::Hold>(locks, "a");
  auto other = std::async(std::launch::async, [&] { NameLocks::Hold hold(locks, "b"); });
  ASSERT_EQ(other.wait_for(std::chrono::seconds(10)), std::future_status::ready);
  auto same = std::async(std::launch::async, [&] { NameLocks::Hold hold(locks, "a"); });
  EXPECT_EQ(same.wait_for(std::chrono::milliseconds(100)), std::future_status::timeout);
  hold_a.reset();
  EXPECT_EQ(same.wait_for(std::chrono::seconds(10)), std::future_status::ready);
}

TEST(NameLocksTest, AWaitEndsAtItsDeadlineHoldingNothing) {
  NameLocks locks;
  NameLocks::Hold first(locks, "a");
  ASSERT_TRUE(first.held());
  {
    NameLocks::Hold late(locks, "a", absl::Now() + absl::Milliseconds(50));
    EXPECT_FALSE(late.held());
  }
  // The late one's end did not free the name: "a" is still the first's.
  NameLocks::Hold again(locks, "a", absl::Now() + absl::Milliseconds(50));
  EXPECT_FALSE(again.held());
  NameLocks::Hold other(locks, "b", absl::Now() + absl::Milliseconds(50));
  EXPECT_TRUE(other.held());
}

}  // namespace
}  // namespace geodesic::server
