// Closes streams whose client stopped taking part: a stream blocked on its
// client (a message the client does not read, or one it does not send) for
// longer than --idle-seconds is cancelled, which ends the blocked Write or
// Read at once, so the handler returns and gives back its stream slot and
// its thread. Time a stream spends on the server's side (computing, waiting
// for a query slot or a graph build) is never idle: only the client can be
// slow here.
#ifndef GEODESIC_SERVER_STREAM_WATCHDOG_H_
#define GEODESIC_SERVER_STREAM_WATCHDOG_H_

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <thread>

#include "absl/base/thread_annotations.h"
#include "absl/container/flat_hash_set.h"
#include "absl/status/status.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"

namespace geodesic::server {

class StreamWatchdog {
 private:
  struct Entry;

 public:
  // Streams blocked on their client longer than `idle` are cancelled (never
  // when `idle` is zero or less), looked at every `tick`.
  explicit StreamWatchdog(absl::Duration idle, absl::Duration tick = absl::Seconds(1));
  ~StreamWatchdog();
  StreamWatchdog(const StreamWatchdog&) = delete;
  StreamWatchdog& operator=(const StreamWatchdog&) = delete;

  // One stream, watched until destroyed.
  class Watch {
   public:
    // While it lives, the stream waits on its client.
    class Waiting {
     public:
      ~Waiting();
      Waiting(const Waiting&) = delete;
      Waiting& operator=(const Waiting&) = delete;

     private:
      friend class Watch;
      explicit Waiting(Watch* watch);
      Watch* watch_;
    };

    Watch(Watch&& other) noexcept;
    Watch& operator=(Watch&&) = delete;
    ~Watch();

    [[nodiscard]] Waiting WaitingOnClient() { return Waiting(this); }
    // The watchdog cancelled the stream for idling.
    bool closed() const;
    // Why a Write or Read failed: the idle limit when the watchdog closed
    // the stream, else the client going away.
    absl::Status Ended() const;

   private:
    friend class StreamWatchdog;
    Watch(StreamWatchdog* owner, Entry* entry) : owner_(owner), entry_(entry) {}
    StreamWatchdog* owner_;
    Entry* entry_;
  };

  // `cancel` ends the stream (ServerContext::TryCancel); it runs on the
  // watchdog's thread while the Watch still lives. `what` names the stream
  // in the log.
  Watch Add(std::string what, std::function<void()> cancel);
  // The same, waiting on its client from now until the Watch is destroyed:
  // for a unary answer being sent.
  Watch AddWaiting(std::string what, std::function<void()> cancel);

  absl::Duration idle() const { return idle_; }
  int watched() const;
  uint64_t closed() const;

 private:
  struct Entry {
    std::string what;
    std::function<void()> cancel;
    // When the stream began to wait on its client; InfiniteFuture while it
    // does not.
    absl::Time waiting_since = absl::InfiniteFuture();
    bool closed = false;
  };

  // Watches `entry` (owned by the Watch returned).
  Watch Track(Entry* entry);
  void Loop();
  // Cancels what waited on its client since before `now - idle_`.
  void CloseIdle(absl::Time now) ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);

  const absl::Duration idle_;
  const absl::Duration tick_;
  mutable absl::Mutex mu_;
  absl::flat_hash_set<Entry*> entries_ ABSL_GUARDED_BY(mu_);
  uint64_t closed_ ABSL_GUARDED_BY(mu_) = 0;
  bool stopping_ ABSL_GUARDED_BY(mu_) = false;
  std::thread thread_;
};

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_STREAM_WATCHDOG_H_
