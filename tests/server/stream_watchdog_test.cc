#include "server/limits/stream_watchdog.h"

#include <atomic>

#include "absl/synchronization/notification.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"

namespace geodesic::server {
namespace {

using ::testing::HasSubstr;

constexpr absl::Duration kIdle = absl::Milliseconds(100);
constexpr absl::Duration kTick = absl::Milliseconds(10);

TEST(StreamWatchdogTest, AStreamWaitingOnItsClientPastTheLimitIsCancelled) {
  StreamWatchdog watchdog(kIdle, kTick);
  absl::Notification cancelled;
  StreamWatchdog::Watch watch = watchdog.Add("MatrixRows from test", [&] { cancelled.Notify(); });
  {
    auto waiting = watch.WaitingOnClient();
    ASSERT_TRUE(cancelled.WaitForNotificationWithTimeout(absl::Seconds(10)));
  }
  EXPECT_TRUE(watch.closed());
  EXPECT_EQ(watchdog.closed(), 1u);
  EXPECT_EQ(watch.Ended().code(), absl::StatusCode::kCancelled);
  EXPECT_THAT(watch.Ended().message(), HasSubstr("--idle-seconds"));
}

TEST(StreamWatchdogTest, TimeOnTheServersSideIsNeverIdle) {
  StreamWatchdog watchdog(kIdle, kTick);
  std::atomic<int> cancels{0};
  StreamWatchdog::Watch watch = watchdog.Add("WatchGraph from test", [&] { ++cancels; });
  // Computing, or waiting for a build: the stream waits on nobody's client.
  absl::SleepFor(5 * kIdle);
  // Short waits on the client, each well within the limit.
  for (int i = 0; i < 10; ++i) {
    auto waiting = watch.WaitingOnClient();
    absl::SleepFor(kIdle / 4);
  }
  EXPECT_EQ(cancels.load(), 0);
  EXPECT_FALSE(watch.closed());
  EXPECT_THAT(watch.Ended().message(), HasSubstr("client went away"));
}

TEST(StreamWatchdogTest, AStreamIsCancelledOnce) {
  StreamWatchdog watchdog(kIdle, kTick);
  std::atomic<int> cancels{0};
  StreamWatchdog::Watch watch = watchdog.Add("UploadMesh from test", [&] { ++cancels; });
  {
    auto waiting = watch.WaitingOnClient();
    absl::SleepFor(5 * kIdle);
  }
  EXPECT_EQ(cancels.load(), 1);
}

TEST(StreamWatchdogTest, ZeroIdleNeverCloses) {
  StreamWatchdog watchdog(absl::ZeroDuration(), kTick);
  std::atomic<int> cancels{0};
  StreamWatchdog::Watch watch = watchdog.Add("GetGeometry from test", [&] { ++cancels; });
  {
    auto waiting = watch.WaitingOnClient();
    absl::SleepFor(absl::Milliseconds(50));
  }
  EXPECT_EQ(cancels.load(), 0);
}

TEST(StreamWatchdogTest, StreamsAreWatchedUntilTheirWatchIsDestroyed) {
  StreamWatchdog watchdog(kIdle, kTick);
  {
    StreamWatchdog::Watch a = watchdog.Add("a", [] {});
    StreamWatchdog::Watch b = watchdog.Add("b", [] {});
    EXPECT_EQ(watchdog.watched(), 2);
  }
  EXPECT_EQ(watchdog.watched(), 0);
}

}  // namespace
}  // namespace geodesic::server
