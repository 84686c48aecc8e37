#include "server/limits/admission.h"

#include <algorithm>
#include <atomic>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/synchronization/notification.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"

namespace geodesic::server {
namespace {

using ::testing::HasSubstr;

absl::Time Soon() { return absl::Now() + absl::Seconds(10); }

AdmissionOptions Limits(int max_inflight, int query_threads, int max_streams = 32) {
  AdmissionOptions o;
  o.max_inflight = max_inflight;
  o.query_threads = query_threads;
  o.max_streams = max_streams;
  return o;
}

AdmissionOptions Limits(int max_inflight, int query_threads, uint64_t memory_limit,
                        std::function<uint64_t()> held,
                        std::function<uint64_t()> pooled_scratch = {}) {
  AdmissionOptions o = Limits(max_inflight, query_threads);
  o.memory_limit = memory_limit;
  o.held = std::move(held);
  o.pooled_scratch = std::move(pooled_scratch);
  return o;
}

TEST(AdmissionTest, QueriesPastMaxInflightAreRefusedWithARetryHint) {
  Admission admission(Limits(2, 1));
  auto a = admission.AdmitQuery("a");
  auto b = admission.AdmitQuery("b");
  ASSERT_TRUE(a.ok());
  ASSERT_TRUE(b.ok());
  auto c = admission.AdmitQuery("c");
  ASSERT_EQ(c.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_THAT(c.status().message(), HasSubstr("server overloaded"));
  EXPECT_THAT(c.status().message(), HasSubstr("retry after"));
  EXPECT_EQ(admission.refusals(), 1u);
  EXPECT_TRUE(admission.overloaded());
  a->Release();
  EXPECT_TRUE(admission.AdmitQuery("c").ok());
}

// A query refused after waiting for a slot saw the slots stay full that
// long: its hint is never shorter than its wait, whatever the mean run.
TEST(AdmissionTest, ARefusalAfterAWaitHintsAtLeastTheWait) {
  Admission admission(Limits(1, 1));
  auto held = admission.AdmitQuery("a");
  ASSERT_TRUE(held.ok());
  const absl::Time asked = absl::Now();
  auto refused = admission.AdmitQuery("b", absl::Now() + absl::Milliseconds(300));
  const absl::Duration waited = absl::Now() - asked;
  ASSERT_EQ(refused.status().code(), absl::StatusCode::kResourceExhausted);
  ASSERT_GE(waited, absl::Milliseconds(300));
  const auto hint = refused.status().GetPayload(kRetryAfterMsTrailer);
  ASSERT_TRUE(hint.has_value());
  int64_t ms = 0;
  ASSERT_TRUE(absl::SimpleAtoi(std::string(*hint), &ms)) << *hint;
  EXPECT_GE(ms, 300);
  EXPECT_LE(ms, absl::ToInt64Milliseconds(waited) + 1);
  // Refused at once, with nothing waited, the hint is the drain estimate.
  auto at_once = admission.AdmitQuery("b");
  ASSERT_EQ(at_once.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_LT(admission.RetryAfterMs(), 300);
}

TEST(AdmissionTest, CountersReturnToZeroWhenTicketsAreGivenBack) {
  Admission admission(Limits(4, 2, 2));
  {
    auto q = admission.AdmitQuery();
    auto r = admission.Run(100, 50, Soon());
    auto s = admission.OpenStream();
    ASSERT_TRUE(q.ok() && r.ok() && s.ok());
    EXPECT_EQ(admission.admitted(), 1);
    EXPECT_EQ(admission.running(), 1);
    EXPECT_EQ(admission.streams(), 1);
    EXPECT_EQ(admission.reserved_bytes(), 150u);
    // Moving a ticket hands it over, and gives back what it replaces.
    Admission::Ticket moved = std::move(*r);
    EXPECT_EQ(admission.running(), 1);
    moved = *admission.Run(1, 1, Soon());
    EXPECT_EQ(admission.running(), 1);
    EXPECT_EQ(admission.reserved_bytes(), 2u);
  }
  EXPECT_EQ(admission.admitted(), 0);
  EXPECT_EQ(admission.running(), 0);
  EXPECT_EQ(admission.waiting(), 0);
  EXPECT_EQ(admission.streams(), 0);
  EXPECT_EQ(admission.reserved_bytes(), 0u);
}

TEST(AdmissionTest, StreamsAreBoundedApartFromQueries) {
  Admission admission(Limits(1, 1, 1));
  auto q = admission.AdmitQuery();
  auto s = admission.OpenStream();
  ASSERT_TRUE(q.ok() && s.ok());
  auto t = admission.OpenStream();
  ASSERT_EQ(t.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_THAT(t.status().message(), HasSubstr("--max-streams"));
}

TEST(AdmissionTest, AClientOpensAtMostItsShareOfTheStreams) {
  Admission admission(Limits(4, 1, 4));
  auto a = admission.OpenStream("flood");
  auto b = admission.OpenStream("flood");
  ASSERT_TRUE(a.ok() && b.ok());
  auto c = admission.OpenStream("flood");
  ASSERT_EQ(c.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_THAT(c.status().message(), HasSubstr("--max-streams-per-client"));
  // Another client still finds room, until every slot is taken.
  auto d = admission.OpenStream("other");
  auto e = admission.OpenStream("other");
  ASSERT_TRUE(d.ok() && e.ok());
  auto f = admission.OpenStream("third");
  ASSERT_EQ(f.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_THAT(f.status().message(), HasSubstr("streams open (--max-streams)"));
  a->Release();
  auto again = admission.OpenStream("flood");
  EXPECT_TRUE(again.ok()) << again.status();
  EXPECT_EQ(admission.streams(), 4);
}

TEST(AdmissionTest, ChangesAreBoundedInAllAndPerClient) {
  AdmissionOptions o = Limits(4, 1);
  o.max_changes = 4;
  Admission admission(o);
  auto a = admission.StartChange("flood");
  auto b = admission.StartChange("flood");
  ASSERT_TRUE(a.ok() && b.ok());
  auto c = admission.StartChange("flood");
  ASSERT_EQ(c.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_THAT(c.status().message(), HasSubstr("this client has 2 registrations"));
  auto d = admission.StartChange("other");
  auto e = admission.StartChange("other");
  ASSERT_TRUE(d.ok() && e.ok());
  auto f = admission.StartChange("third");
  ASSERT_EQ(f.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_THAT(f.status().message(), HasSubstr("4 registrations, unloads and graph requests"));
  // Changes take no stream or query slot.
  EXPECT_TRUE(admission.OpenStream("third").ok());
  EXPECT_TRUE(admission.AdmitQuery("third").ok());
  a->Release();
  auto again = admission.StartChange("flood");
  EXPECT_TRUE(again.ok()) << again.status();
}

TEST(AdmissionTest, AtMostQueryThreadsRunAndTheRestRunInArrivalOrder) {
  Admission admission(Limits(16, 2));
  auto first = admission.Run(0, 0, Soon());
  auto second = admission.Run(0, 0, Soon());
  ASSERT_TRUE(first.ok() && second.ok());
  std::mutex mu;
  std::vector<int> order;
  std::atomic<int> peak{0}, now{0};
  std::vector<std::thread> waiters;
  for (int i = 0; i < 6; ++i) {
    waiters.emplace_back([&, i] {
      auto run = admission.Run(0, 0, Soon());
      ASSERT_TRUE(run.ok());
      const int n = ++now;
      for (int p = peak; n > p && !peak.compare_exchange_weak(p, n);) {
      }
      {
        std::lock_guard<std::mutex> lock(mu);
        order.push_back(i);
      }
      absl::SleepFor(absl::Milliseconds(5));
      --now;
    });
    // Each in line before the next arrives.
    while (admission.waiting() < i + 1) absl::SleepFor(absl::Milliseconds(1));
  }
  first->Release();
  second->Release();
  for (auto& t : waiters) t.join();
  EXPECT_LE(peak.load(), 2);
  // Two run at once, so neighbours may swap as they record; none overtakes
  // by more than that.
  for (size_t k = 0; k < order.size(); ++k) EXPECT_LE(std::abs(order[k] - int(k)), 1);
  EXPECT_EQ(admission.running(), 0);
}

TEST(AdmissionTest, AWaitingQueryIsAnsweredOverloadedAtItsDeadline) {
  Admission admission(Limits(4, 1));
  auto busy = admission.Run(0, 0, Soon());
  ASSERT_TRUE(busy.ok());
  const absl::Time start = absl::Now();
  auto late = admission.Run(0, 0, absl::Now() + absl::Milliseconds(100));
  EXPECT_EQ(late.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_THAT(late.status().message(), HasSubstr("deadline"));
  EXPECT_LT(absl::Now() - start, absl::Seconds(2));
  EXPECT_EQ(admission.waiting(), 0);
}

TEST(AdmissionTest, AWaitingQueryStopsWhenCancelled) {
  Admission admission(Limits(4, 1));
  auto busy = admission.Run(0, 0, Soon());
  std::atomic<bool> cancel{false};
  std::thread t([&] {
    absl::SleepFor(absl::Milliseconds(50));
    cancel = true;
  });
  auto waited = admission.Run(0, 0, Soon(), [&] { return cancel.load(); });
  t.join();
  EXPECT_EQ(waited.status().code(), absl::StatusCode::kCancelled);
  EXPECT_EQ(admission.waiting(), 0);
}

TEST(AdmissionTest, ReservationsWaitForMemoryAndNeverExceedTheLimit) {
  std::atomic<uint64_t> held{400};
  Admission admission(Limits(8, 4, 1000, [&] { return held.load(); }));
  auto a = admission.Run(300, 100, Soon());  // 800 of 1000
  ASSERT_TRUE(a.ok());
  absl::Notification ran;
  std::thread t([&] {
    auto b = admission.Run(250, 50, Soon());  // 300 more: waits for a
    ASSERT_TRUE(b.ok());
    EXPECT_LE(held + admission.reserved_bytes(), 1000u);
    ran.Notify();
  });
  absl::SleepFor(absl::Milliseconds(100));
  EXPECT_FALSE(ran.HasBeenNotified());
  EXPECT_EQ(admission.waiting(), 1);
  a->Release();
  t.join();
  EXPECT_TRUE(ran.HasBeenNotified());
  EXPECT_EQ(admission.reserved_bytes(), 0u);
}

TEST(AdmissionTest, AQueryThatCanNeverFitIsRefusedAtOnceNamingItsSize) {
  AdmissionOptions options = Limits(8, 4, 1000, [] { return uint64_t{900}; });
  options.pinned = [] { return uint64_t{850}; };
  Admission admission(options);
  auto r = admission.Run(150, 50, Soon());
  ASSERT_EQ(r.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_THAT(r.status().message(), HasSubstr("200 bytes"));
  EXPECT_EQ(admission.waiting(), 0);
}

TEST(AdmissionTest, WithNothingRunningTheFrontQueryRunsWhateverEvictableMemoryIsHeld) {
  Admission admission(Limits(8, 4, 1000, [] { return uint64_t{950}; }));
  auto alone = admission.Run(100, 100, Soon());
  ASSERT_TRUE(alone.ok()) << alone.status();
  // Beside a running query the next one waits for memory.
  auto next = admission.Run(100, 0, absl::Now() + absl::Milliseconds(100));
  EXPECT_EQ(next.status().code(), absl::StatusCode::kResourceExhausted);
}

TEST(AdmissionTest, AnswersKeptForTheirClientsAreNotEvictableWhenNothingRuns) {
  Admission admission(Limits(8, 4, 1000, [] { return uint64_t{0}; }));
  auto first = admission.Run(600, 0, Soon());
  ASSERT_TRUE(first.ok()) << first.status();
  // Its answer waits for a client that may never read it: with nothing
  // running, the next query still must fit beside it.
  Admission::Ticket kept = admission.KeepAnswer(std::move(*first));
  EXPECT_EQ(admission.running(), 0);
  auto next = admission.Run(600, 0, absl::Now() + absl::Milliseconds(100));
  EXPECT_EQ(next.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_TRUE(admission.Run(300, 0, Soon()).ok());
  kept.Release();
  EXPECT_TRUE(admission.Run(600, 0, Soon()).ok());
}

TEST(AdmissionTest, IdleScratchCountsAsHeldButRunningScratchOnlyOnce) {
  std::atomic<uint64_t> pooled{0};
  Admission admission(Limits(
      8, 4, 1000, [] { return uint64_t{0}; }, [&] { return pooled.load(); }));
  auto a = admission.Run(100, 400, Soon());
  ASSERT_TRUE(a.ok());
  pooled = 400;  // a's scratch, leased from the engine's pool
  auto b = admission.Run(100, 300, absl::Now() + absl::Milliseconds(200));
  EXPECT_TRUE(b.ok()) << b.status();  // 900: a's scratch is not counted twice
  b->Release();
  a->Release();
  pooled = 800;  // idle now, kept by the pool
  auto c = admission.Run(100, 0, Soon());
  ASSERT_TRUE(c.ok());  // runs alone
  auto d = admission.Run(150, 0, absl::Now() + absl::Milliseconds(100));
  EXPECT_EQ(d.status().code(), absl::StatusCode::kResourceExhausted);
}

TEST(AdmissionTest, AnAnswerKeptForItsClientFreesTheThreadButNotTheMemory) {
  Admission admission(Limits(8, 1, 1000, [] { return uint64_t{0}; }));
  auto block = admission.Run(400, 300, Soon());
  ASSERT_TRUE(block.ok());
  Admission::Ticket sending = admission.KeepAnswer(std::move(*block));
  EXPECT_EQ(admission.running(), 0);
  EXPECT_EQ(admission.reserved_bytes(), 400u);
  // The one query thread is free for another query beside the kept answer.
  auto light = admission.Run(100, 100, absl::Now() + absl::Milliseconds(200));
  ASSERT_TRUE(light.ok()) << light.status();
  EXPECT_EQ(admission.reserved_bytes(), 600u);
  light->Release();
  sending.Release();
  EXPECT_EQ(admission.reserved_bytes(), 0u);
}

TEST(AdmissionTest, AKeptAnswerCountsAgainstTheMemoryOfQueriesThatRunBesideIt) {
  Admission admission(Limits(8, 2, 1000, [] { return uint64_t{0}; }));
  auto block = admission.Run(500, 0, Soon());
  ASSERT_TRUE(block.ok());
  Admission::Ticket sending = admission.KeepAnswer(std::move(*block));
  auto a = admission.Run(200, 0, Soon());
  ASSERT_TRUE(a.ok());
  // 500 kept + 200 running + 400 would pass the limit: it waits, then is refused.
  auto b = admission.Run(400, 0, absl::Now() + absl::Milliseconds(100));
  EXPECT_EQ(b.status().code(), absl::StatusCode::kResourceExhausted);
  sending.Release();
  auto c = admission.Run(400, 0, Soon());
  EXPECT_TRUE(c.ok()) << c.status();
}

TEST(AdmissionTest, ASlicedCallKeepsItsAnswerReservedBetweenSlices) {
  Admission admission(Limits(8, 1, 1000, [] { return uint64_t{0}; }));
  auto slice = admission.Run(400, 300, Soon());
  ASSERT_TRUE(slice.ok());
  // Between slices: the thread and the scratch go back, the answer stays.
  Admission::Ticket kept = admission.KeepAnswer(std::move(*slice));
  EXPECT_EQ(admission.reserved_bytes(), 400u);
  auto next = admission.Run(0, 300, Soon());
  ASSERT_TRUE(next.ok()) << next.status();
  Admission::Ticket run = admission.Adopt(std::move(*next), std::move(kept));
  EXPECT_FALSE(kept.held());
  EXPECT_EQ(admission.reserved_bytes(), 700u);
  EXPECT_EQ(admission.running(), 1);
  run.Release();
  EXPECT_EQ(admission.reserved_bytes(), 0u);
  EXPECT_EQ(admission.running(), 0);
}

// Runs `client`'s query on a thread once it is in line, recording its name
// in `order` when it gets a slot and holding the slot until `release`.
class Waiter {
 public:
  Waiter(Admission& admission, std::string client, std::string name, std::mutex& mu,
         std::vector<std::string>& order)
      : thread_([&admission, client, name, &mu, &order, this] {
          auto run = admission.Run(0, 0, Soon(), {}, client);
          ASSERT_TRUE(run.ok()) << run.status();
          {
            std::lock_guard<std::mutex> lock(mu);
            order.push_back(name);
          }
          release_.WaitForNotification();
        }) {}
  ~Waiter() {
    Release();
    thread_.join();
  }
  void Release() {
    if (!release_.HasBeenNotified()) release_.Notify();
  }

 private:
  absl::Notification release_;
  std::thread thread_;
};

void WaitUntilWaiting(const Admission& admission, int n) {
  while (admission.waiting() < n) absl::SleepFor(absl::Milliseconds(1));
}

void WaitUntilRan(std::mutex& mu, const std::vector<std::string>& order, size_t n) {
  while (true) {
    {
      std::lock_guard<std::mutex> lock(mu);
      if (order.size() >= n) return;
    }
    absl::SleepFor(absl::Milliseconds(1));
  }
}

TEST(AdmissionTest, FreeSlotsGoToTheWaitingClientsInTurn) {
  Admission admission(Limits(16, 1));
  auto busy = admission.Run(0, 0, Soon(), {}, "heavy");
  ASSERT_TRUE(busy.ok());
  std::mutex mu;
  std::vector<std::string> order;
  std::vector<std::unique_ptr<Waiter>> waiters;
  // Three of one client's queries wait before the other client's one.
  for (const char* name : {"heavy1", "heavy2", "heavy3"}) {
    waiters.push_back(std::make_unique<Waiter>(admission, "heavy", name, mu, order));
    WaitUntilWaiting(admission, static_cast<int>(waiters.size()));
  }
  waiters.push_back(std::make_unique<Waiter>(admission, "light", "light1", mu, order));
  WaitUntilWaiting(admission, 4);
  busy->Release();
  // Each query gives its slot back once it ran, and the next one runs.
  const std::vector<std::string> names = {"heavy1", "heavy2", "heavy3", "light1"};
  for (size_t k = 0; k < waiters.size(); ++k) {
    WaitUntilRan(mu, order, k + 1);
    std::string last;
    {
      std::lock_guard<std::mutex> lock(mu);
      last = order.back();
    }
    waiters[std::find(names.begin(), names.end(), last) - names.begin()]->Release();
  }
  waiters.clear();
  // The light client's query did not wait behind all of the heavy one's.
  EXPECT_THAT(order, ::testing::ElementsAre("heavy1", "light1", "heavy2", "heavy3"));
  EXPECT_EQ(admission.running(), 0);
  EXPECT_EQ(admission.waiting(), 0);
}

TEST(AdmissionTest, AClientRunsAtMostItsShareOfTheSlotsWhileOthersWait) {
  Admission admission(Limits(16, 2));
  // Alone, a client may take every slot.
  auto first = admission.Run(0, 0, Soon(), {}, "heavy");
  auto second = admission.Run(0, 0, Soon(), {}, "heavy");
  ASSERT_TRUE(first.ok() && second.ok());
  std::mutex mu;
  std::vector<std::string> order;
  auto heavy = std::make_unique<Waiter>(admission, "heavy", "heavy", mu, order);
  WaitUntilWaiting(admission, 1);
  auto light = std::make_unique<Waiter>(admission, "light", "light", mu, order);
  WaitUntilWaiting(admission, 2);
  // The heavy client asked first, but holds one slot of two while the
  // light one waits: the freed slot is the light client's.
  first->Release();
  WaitUntilRan(mu, order, 1);
  {
    std::lock_guard<std::mutex> lock(mu);
    EXPECT_EQ(order.front(), "light");
  }
  EXPECT_EQ(admission.waiting(), 1);
  second->Release();
  WaitUntilRan(mu, order, 2);
  heavy.reset();
  light.reset();
  EXPECT_EQ(admission.running(), 0);
}

TEST(AdmissionTest, AClientAloneMayTakeEverySlotAndItsShareBindsOnceAnotherIsThere) {
  // A share of 3 (half of max_inflight).
  Admission admission(Limits(6, 1));
  std::vector<Admission::Ticket> flood;
  for (int k = 0; k < 4; ++k) {
    auto t = admission.AdmitQuery("flood");
    ASSERT_TRUE(t.ok()) << "alone, query " << k << ": " << t.status();
    flood.push_back(std::move(*t));
  }
  // Another client finds room, and from then on the flood is held to its
  // share although slots are free.
  auto other = admission.AdmitQuery("other");
  ASSERT_TRUE(other.ok()) << other.status();
  auto past_share = admission.AdmitQuery("flood");
  ASSERT_EQ(past_share.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_THAT(past_share.status().message(), HasSubstr("--max-inflight-per-client"));
  EXPECT_EQ(std::string(*past_share.status().GetPayload(kRetryAfterMsTrailer)).empty(), false);
  // Once the other client is gone, the flood has the whole server again.
  other->Release();
  EXPECT_TRUE(admission.AdmitQuery("flood").ok());
}

TEST(AdmissionTest, AQueryFindingAdmissionFullWaitsAndASlotGoesToTheClientWithFewest) {
  Admission admission(Limits(2, 1));
  auto a1 = admission.AdmitQuery("a");
  auto a2 = admission.AdmitQuery("a");
  ASSERT_TRUE(a1.ok() && a2.ok());
  // Full: without time to wait, refused at once.
  EXPECT_EQ(admission.AdmitQuery("b").status().code(), absl::StatusCode::kResourceExhausted);
  // With time, a's third query and then b's wait; the slot a gives back
  // goes to b, which has none, although a asked first.
  std::atomic<bool> a3_admitted{false}, b_admitted{false};
  std::thread a3([&] {
    auto t = admission.AdmitQuery("a", Soon());
    a3_admitted = t.ok();
  });
  while (admission.admission_waiting() < 1) absl::SleepFor(absl::Milliseconds(1));
  Admission::Ticket b_ticket;
  std::thread b([&] {
    auto t = admission.AdmitQuery("b", Soon());
    b_admitted = t.ok();
    if (t.ok()) b_ticket = std::move(*t);
  });
  while (admission.admission_waiting() < 2) absl::SleepFor(absl::Milliseconds(1));
  a1->Release();
  b.join();
  EXPECT_TRUE(b_admitted);
  EXPECT_FALSE(a3_admitted);
  EXPECT_EQ(admission.admitted(), 2);
  b_ticket.Release();
  a3.join();
  EXPECT_TRUE(a3_admitted);
  EXPECT_EQ(admission.admission_waiting(), 0);
}

TEST(AdmissionTest, AWaitForAdmissionEndsAtItsTimeOrWhenCancelled) {
  Admission admission(Limits(1, 1));
  auto held = admission.AdmitQuery("a");
  ASSERT_TRUE(held.ok());
  const absl::Time start = absl::Now();
  auto late = admission.AdmitQuery("b", start + absl::Milliseconds(100));
  EXPECT_EQ(late.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_GE(absl::Now() - start, absl::Milliseconds(100));
  auto cancelled = admission.AdmitQuery("b", Soon(), [] { return true; });
  EXPECT_EQ(cancelled.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_EQ(admission.admission_waiting(), 0);
  held->Release();
  EXPECT_TRUE(admission.AdmitQuery("b").ok());
}

TEST(AdmissionTest, OthersWaitingSeesOnlyOtherClients) {
  Admission admission(Limits(16, 1));
  auto busy = admission.Run(0, 0, Soon(), {}, "a");
  ASSERT_TRUE(busy.ok());
  std::mutex mu;
  std::vector<std::string> order;
  {
    Waiter same(admission, "a", "a", mu, order);
    WaitUntilWaiting(admission, 1);
    EXPECT_FALSE(admission.OthersWaiting("a"));
    EXPECT_TRUE(admission.OthersWaiting("b"));
    busy->Release();
  }
}

}  // namespace
}  // namespace geodesic::server
