#include "server/limits/admission.h"

#include <algorithm>
#include <utility>

#include "absl/cleanup/cleanup.h"
#include "absl/strings/cord.h"
#include "absl/strings/str_format.h"

namespace geodesic::server {
namespace {

// How often a waiting query looks whether its client went away.
constexpr absl::Duration kCancelPoll = absl::Milliseconds(50);
// How long a refusal keeps overloaded() true: long enough for a probe that
// polls every second to see it.
constexpr absl::Duration kOverloadMemory = absl::Seconds(1);

}  // namespace

Admission::Ticket& Admission::Ticket::operator=(Ticket&& other) noexcept {
  if (this != &other) {
    Release();
    owner_ = std::exchange(other.owner_, nullptr);
    kind_ = other.kind_;
    client_ = std::move(other.client_);
    answer_ = other.answer_;
    scratch_ = other.scratch_;
    start_ = other.start_;
  }
  return *this;
}

void Admission::Ticket::Release() {
  if (Admission* owner = std::exchange(owner_, nullptr)) owner->Release(*this);
}

Admission::Admission(AdmissionOptions options) : options_(std::move(options)) {}

absl::Status Admission::Refuse(const std::string& what, int64_t retry_after_ms) {
  refusals_.fetch_add(1, std::memory_order_relaxed);
  absl::Status refusal = absl::ResourceExhaustedError(
      absl::StrFormat("server overloaded: %s; retry after %d ms", what, retry_after_ms));
  refusal.SetPayload(kRetryAfterMsTrailer, absl::Cord(std::to_string(retry_after_ms)));
  return refusal;
}

int Admission::InflightPerClient() const {
  if (options_.max_inflight_per_client > 0) return options_.max_inflight_per_client;
  return std::max(1, options_.max_inflight / 2);
}

struct Admission::AdmitWaiter {
  std::string client;
  absl::CondVar cv;
  bool granted = false;
};

bool Admission::MayTakeSlotLocked(const std::string& client) const {
  if (clients_.at(client).admitted < InflightPerClient()) return true;
  for (const auto& [key, c] : clients_) {
    if (key != client && (c.admitted > 0 || c.admit_waiting > 0)) return false;
  }
  return true;
}

void Admission::AdmitLocked(const std::string& client) {
  ++admitted_;
  ++clients_[client].admitted;
}

void Admission::GrantLocked() {
  while (admitted_ < options_.max_inflight) {
    AdmitWaiter* best = nullptr;
    for (AdmitWaiter* w : admit_waiters_) {
      if (w->granted || !MayTakeSlotLocked(w->client)) continue;
      if (best == nullptr || clients_.at(w->client).admitted < clients_.at(best->client).admitted) {
        best = w;
      }
    }
    if (best == nullptr) return;
    best->granted = true;
    AdmitLocked(best->client);
    best->cv.Signal();
  }
}

absl::StatusOr<Admission::Ticket> Admission::AdmitQuery(const std::string& client,
                                                        absl::Time wait_until,
                                                        const std::function<bool()>& cancelled) {
  const absl::Time arrived = absl::Now();
  std::string what;
  {
    absl::MutexLock lock(&mu_);
    Client& c = clients_[client];
    // Nobody passes those already waiting.
    if (admit_waiters_.empty() && admitted_ < options_.max_inflight && MayTakeSlotLocked(client)) {
      AdmitLocked(client);
      return Ticket(this, Kind::kQuery, client, 0, 0);
    }
    if (absl::Now() < wait_until &&
        admit_waiters_.size() < static_cast<size_t>(options_.max_inflight)) {
      AdmitWaiter waiter;
      waiter.client = client;
      admit_waiters_.push_back(&waiter);
      ++c.admit_waiting;
      GrantLocked();
      while (!waiter.granted && absl::Now() < wait_until && !(cancelled && cancelled())) {
        waiter.cv.WaitWithDeadline(&mu_, std::min(wait_until, absl::Now() + kCancelPoll));
      }
      admit_waiters_.erase(std::find(admit_waiters_.begin(), admit_waiters_.end(), &waiter));
      --c.admit_waiting;
      if (waiter.granted) return Ticket(this, Kind::kQuery, client, 0, 0);
      // Its leaving may end another client's wait for its share.
      GrantLocked();
    }
    last_refusal_ = absl::Now();
    what = admitted_ >= options_.max_inflight
               ? absl::StrFormat("%d queries admitted (--max-inflight)", options_.max_inflight)
               : absl::StrFormat(
                     "this client has %d queries admitted, its share of them "
                     "(--max-inflight-per-client)",
                     c.admitted);
    ForgetIfIdleLocked(client);
  }
  return Refuse(what, RetryAfterMs(absl::Now() - arrived));
}

absl::StatusOr<Admission::Ticket> Admission::OpenStream(const std::string& client) {
  const int mine = options_.max_streams_per_client > 0 ? options_.max_streams_per_client
                                                       : std::max(1, options_.max_streams / 2);
  return OpenSlot(Kind::kStream, client, options_.max_streams, mine, "streams open",
                  "--max-streams", "--max-streams-per-client");
}

absl::StatusOr<Admission::Ticket> Admission::StartChange(const std::string& client) {
  return OpenSlot(Kind::kChange, client, options_.max_changes,
                  std::max(1, options_.max_changes / 2),
                  "registrations, unloads and graph requests in progress", "the most at once",
                  "half of the most at once");
}

absl::StatusOr<Admission::Ticket> Admission::OpenSlot(Kind kind, const std::string& client, int max,
                                                      int max_mine, const char* what,
                                                      const char* flag, const char* client_flag) {
  std::string refusal;
  {
    absl::MutexLock lock(&mu_);
    int& open = kind == Kind::kStream ? streams_ : changes_;
    Client& c = clients_[client];
    int& mine = kind == Kind::kStream ? c.streams : c.changes;
    if (open < max && mine < max_mine) {
      ++open;
      ++mine;
      return Ticket(this, kind, client, 0, 0);
    }
    last_refusal_ = absl::Now();
    refusal = open >= max ? absl::StrFormat("%d %s (%s)", max, what, flag)
                          : absl::StrFormat("this client has %d %s, its share of them (%s)", mine,
                                            what, client_flag);
    ForgetIfIdleLocked(client);
  }
  return Refuse(refusal, RetryAfterMs());
}

uint64_t Admission::UnevictableLocked() const {
  return (options_.pinned ? options_.pinned() : 0) + reserved_answer_;
}

uint64_t Admission::UsedLocked() const {
  const uint64_t held = options_.held ? options_.held() : 0;
  const uint64_t pooled = options_.pooled_scratch ? options_.pooled_scratch() : 0;
  const uint64_t idle_scratch = pooled > reserved_scratch_ ? pooled - reserved_scratch_ : 0;
  return held + idle_scratch + reserved_answer_ + reserved_scratch_;
}

uint64_t Admission::NextLocked() const {
  if (turns_.empty()) return 0;
  int active = 0;
  for (const auto& [key, c] : clients_) active += c.running > 0 || !c.waiting.empty();
  const int threads = std::max(1, options_.query_threads);
  const int share = std::max(1, (threads + active - 1) / std::max(1, active));
  for (const std::string& key : turns_) {
    const Client& c = clients_.at(key);
    if (c.running < share) return c.waiting.front();
  }
  return clients_.at(turns_.front()).waiting.front();
}

void Admission::LeaveQueueLocked(const std::string& client, uint64_t number) {
  Client& c = clients_[client];
  c.waiting.erase(std::find(c.waiting.begin(), c.waiting.end(), number));
  --waiting_;
  auto turn = std::find(turns_.begin(), turns_.end(), client);
  if (turn != turns_.end()) turns_.erase(turn);
  // A client keeps its turns for as long as it has queries waiting, and
  // goes behind the others once served.
  if (!c.waiting.empty()) turns_.push_back(client);
}

void Admission::WakeNextLocked() {
  if (auto it = run_waiters_.find(NextLocked()); it != run_waiters_.end()) it->second->Signal();
}

void Admission::ForgetIfIdleLocked(const std::string& client) {
  auto it = clients_.find(client);
  if (it != clients_.end() && it->second.admitted == 0 && it->second.running == 0 &&
      it->second.streams == 0 && it->second.changes == 0 && it->second.admit_waiting == 0 &&
      it->second.waiting.empty()) {
    clients_.erase(it);
  }
}

bool Admission::OthersWaiting(const std::string& client) const {
  absl::MutexLock lock(&mu_);
  for (const std::string& key : turns_) {
    if (key != client) return true;
  }
  return false;
}

absl::StatusOr<Admission::Ticket> Admission::Run(uint64_t answer_bytes, uint64_t scratch_bytes,
                                                 absl::Time deadline,
                                                 const std::function<bool()>& cancelled,
                                                 const std::string& client) {
  const absl::Time arrived = absl::Now();
  const uint64_t want = answer_bytes + scratch_bytes;
  const uint64_t limit = options_.memory_limit;
  absl::MutexLock lock(&mu_);
  if (limit > 0) {
    const uint64_t pinned = options_.pinned ? options_.pinned() : 0;
    if (pinned + want > limit) {
      const uint64_t free = pinned < limit ? limit - pinned : 0;
      return absl::ResourceExhaustedError(absl::StrFormat(
          "the query needs %u bytes (answer %u, scratch %u) but only %u of the memory limit "
          "(%u bytes) are left beside the registered meshes: ask for less at once",
          want, answer_bytes, scratch_bytes, free, limit));
    }
  }
  const uint64_t number = next_number_++;
  Client& self = clients_[client];
  self.waiting.push_back(number);
  ++waiting_;
  if (std::find(turns_.begin(), turns_.end(), client) == turns_.end()) turns_.push_back(client);
  absl::CondVar turn;
  run_waiters_[number] = &turn;
  absl::Cleanup forget_turn = [&] { run_waiters_.erase(number); };
  auto leave = [&] {
    LeaveQueueLocked(client, number);
    ForgetIfIdleLocked(client);
    WakeNextLocked();
  };
  while (true) {
    // Only the query whose turn it is asks for memory: the held() callbacks
    // take the cache's lock. With nothing running, what is held can only
    // shrink by evictions the cache makes on its own: that query runs rather
    // than wait on them (the limit is then passed by one query at most), but
    // only beside what no eviction frees: meshes, and answers waiting for
    // their clients, which may never read them.
    if (running_ < options_.query_threads && NextLocked() == number &&
        (limit == 0 || UsedLocked() + want <= limit ||
         (running_ == 0 && UnevictableLocked() + want <= limit))) {
      LeaveQueueLocked(client, number);
      ++running_;
      ++clients_[client].running;
      reserved_answer_ += answer_bytes;
      reserved_scratch_ += scratch_bytes;
      // The next in line may fit beside this one.
      WakeNextLocked();
      Ticket t(this, Kind::kRun, client, answer_bytes, scratch_bytes);
      t.start_ = absl::Now();
      return t;
    }
    if (cancelled && cancelled()) {
      leave();
      return absl::CancelledError("cancelled while waiting for a query slot");
    }
    const absl::Time now = absl::Now();
    if (now >= deadline) {
      leave();
      last_refusal_ = now;
      return Refuse(absl::StrFormat("the call's deadline came while %d queries were running "
                                    "and %d waiting",
                                    running_, waiting_),
                    RetryAfterMsLocked(now - arrived));
    }
    turn.WaitWithDeadline(&mu_, std::min(deadline, now + kCancelPoll));
  }
}

Admission::Ticket Admission::KeepAnswer(Ticket run) {
  if (run.owner_ != this || run.kind_ != Kind::kRun) return run;
  const uint64_t answer = run.answer_;
  {
    absl::MutexLock lock(&mu_);
    // Counted in the answer ticket from here on.
    reserved_answer_ += answer;
  }
  run.Release();
  return Ticket(this, Kind::kAnswer, run.client_, answer, 0);
}

Admission::Ticket Admission::Adopt(Ticket run, Ticket kept) {
  if (run.owner_ != this || kept.owner_ != this || kept.kind_ != Kind::kAnswer) return run;
  // The bytes stay in reserved_answer_: only the ticket that gives them back
  // changes.
  run.answer_ += std::exchange(kept.answer_, 0);
  kept.owner_ = nullptr;
  return run;
}

void Admission::Release(const Ticket& t) {
  absl::MutexLock lock(&mu_);
  switch (t.kind_) {
    case Kind::kQuery:
      --admitted_;
      --clients_[t.client_].admitted;
      ForgetIfIdleLocked(t.client_);
      GrantLocked();
      break;
    case Kind::kStream:
      --streams_;
      --clients_[t.client_].streams;
      ForgetIfIdleLocked(t.client_);
      break;
    case Kind::kChange:
      --changes_;
      --clients_[t.client_].changes;
      ForgetIfIdleLocked(t.client_);
      break;
    case Kind::kAnswer:
      reserved_answer_ -= t.answer_;
      WakeNextLocked();
      break;
    case Kind::kRun: {
      --running_;
      --clients_[t.client_].running;
      ForgetIfIdleLocked(t.client_);
      reserved_answer_ -= t.answer_;
      reserved_scratch_ -= t.scratch_;
      const double seconds = absl::ToDoubleSeconds(absl::Now() - t.start_);
      mean_run_seconds_ = 0.9 * mean_run_seconds_ + 0.1 * seconds;
      WakeNextLocked();
      break;
    }
  }
}

int64_t Admission::RetryAfterMs(absl::Duration waited) const {
  absl::MutexLock lock(&mu_);
  return RetryAfterMsLocked(waited);
}

int64_t Admission::RetryAfterMsLocked(absl::Duration waited) const {
  // The admitted drain through query_threads slots, a mean run each; but
  // never shorter than the refused call's own wait, in which the slots
  // stayed full (slow queries, answers not taken): a shorter hint would
  // bring it back to the same queue at once.
  const double rounds = 1.0 + static_cast<double>(admitted_) / std::max(1, options_.query_threads);
  const double ms = std::max(1e3 * mean_run_seconds_ * rounds, absl::ToDoubleMilliseconds(waited));
  return std::clamp<int64_t>(static_cast<int64_t>(ms), 10, 10000);
}

int Admission::admitted() const {
  absl::MutexLock lock(&mu_);
  return admitted_;
}

int Admission::admission_waiting() const {
  absl::MutexLock lock(&mu_);
  return static_cast<int>(admit_waiters_.size());
}

int Admission::running() const {
  absl::MutexLock lock(&mu_);
  return running_;
}

int Admission::waiting() const {
  absl::MutexLock lock(&mu_);
  return waiting_;
}

int Admission::streams() const {
  absl::MutexLock lock(&mu_);
  return streams_;
}

uint64_t Admission::reserved_bytes() const {
  absl::MutexLock lock(&mu_);
  return reserved_answer_ + reserved_scratch_;
}

bool Admission::overloaded() const {
  absl::MutexLock lock(&mu_);
  return admitted_ >= options_.max_inflight || streams_ >= options_.max_streams ||
         absl::Now() - last_refusal_ < kOverloadMemory;
}

}  // namespace geodesic::server
