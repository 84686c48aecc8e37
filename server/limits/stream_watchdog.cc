#include "server/limits/stream_watchdog.h"

#include <utility>

#include "absl/strings/str_format.h"
#include "server/base/log.h"

namespace geodesic::server {

StreamWatchdog::StreamWatchdog(absl::Duration idle, absl::Duration tick)
    : idle_(idle), tick_(tick) {
  if (idle_ > absl::ZeroDuration()) thread_ = std::thread([this] { Loop(); });
}

StreamWatchdog::~StreamWatchdog() {
  {
    absl::MutexLock lock(&mu_);
    stopping_ = true;
  }
  if (thread_.joinable()) thread_.join();
}

void StreamWatchdog::Loop() {
  absl::MutexLock lock(&mu_);
  while (!stopping_) {
    // Woken early only to stop.
    mu_.AwaitWithTimeout(absl::Condition(&stopping_), tick_);
    if (!stopping_) CloseIdle(absl::Now());
  }
}

void StreamWatchdog::CloseIdle(absl::Time now) {
  for (Entry* e : entries_) {
    if (e->closed || now - e->waiting_since < idle_) continue;
    e->closed = true;
    ++closed_;
    // Under the lock: the Watch, and the call it cancels, outlive this.
    e->cancel();
    Log(LogLevel::kWarning, "stream_idle_closed",
        {{"stream", e->what},
         {"idle_seconds", absl::ToDoubleSeconds(idle_)},
         {"waited_seconds", absl::ToDoubleSeconds(now - e->waiting_since)}});
  }
}

StreamWatchdog::Watch StreamWatchdog::Add(std::string what, std::function<void()> cancel) {
  return Track(new Entry{std::move(what), std::move(cancel)});
}

StreamWatchdog::Watch StreamWatchdog::AddWaiting(std::string what, std::function<void()> cancel) {
  return Track(new Entry{std::move(what), std::move(cancel), absl::Now()});
}

StreamWatchdog::Watch StreamWatchdog::Track(Entry* entry) {
  absl::MutexLock lock(&mu_);
  entries_.insert(entry);
  return Watch(this, entry);
}

int StreamWatchdog::watched() const {
  absl::MutexLock lock(&mu_);
  return static_cast<int>(entries_.size());
}

uint64_t StreamWatchdog::closed() const {
  absl::MutexLock lock(&mu_);
  return closed_;
}

StreamWatchdog::Watch::Watch(Watch&& other) noexcept
    : owner_(std::exchange(other.owner_, nullptr)), entry_(std::exchange(other.entry_, nullptr)) {}

StreamWatchdog::Watch::~Watch() {
  if (!owner_) return;
  {
    absl::MutexLock lock(&owner_->mu_);
    owner_->entries_.erase(entry_);
  }
  delete entry_;
}

bool StreamWatchdog::Watch::closed() const {
  absl::MutexLock lock(&owner_->mu_);
  return entry_->closed;
}

absl::Status StreamWatchdog::Watch::Ended() const {
  if (!closed()) return absl::CancelledError("client went away");
  return absl::CancelledError(
      absl::StrFormat("the stream was closed after waiting on its client for %g s (--idle-seconds)",
                      absl::ToDoubleSeconds(owner_->idle_)));
}

StreamWatchdog::Watch::Waiting::Waiting(Watch* watch) : watch_(watch) {
  absl::MutexLock lock(&watch_->owner_->mu_);
  watch_->entry_->waiting_since = absl::Now();
}

StreamWatchdog::Watch::Waiting::~Waiting() {
  absl::MutexLock lock(&watch_->owner_->mu_);
  watch_->entry_->waiting_since = absl::InfiniteFuture();
}

}  // namespace geodesic::server
