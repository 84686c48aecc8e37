// Admission control for the daemon's calls: how many queries are admitted,
// how many of them run at once, how much memory they reserve, and how many
// streams are open.
//
// Overload is an answer, not a failure (Envoy's and nginx's habit): a query
// past --max-inflight, or a stream past --max-streams, is refused at once with
// RESOURCE_EXHAUSTED and a retry hint, while every query admitted is answered.
// Admitted queries run at most `query_threads` at a time, each with its
// answer and scratch bytes reserved against the memory limit, so that CPU and
// memory stay bounded however many clients wait. Calls that are neither
// (health, listing, get, cancel, unload) pass untouched.
//
// Fair share: queries are keyed by client (client_key.h). Each client's
// waiting queries run in the order it sent them, and free slots go to the
// waiting clients in turn, so one client's heavy calls do not hold up
// another's light ones. Shares are work-conserving: they bind only while
// another client is there. A client alone may have every admission slot
// and every run slot; while other clients have queries admitted, a client
// is admitted at most max_inflight_per_client queries, and while they wait,
// it runs at most its share of the slots. A query that finds admission full
// waits a short, bounded time for a slot rather than being refused at once
// (a crowd's goodput would otherwise collapse into retries), and a slot
// given back goes straight to the waiting client with the fewest admitted,
// not to whoever asks next. Each waiter is woken alone when its turn comes,
// never the whole crowd at once. Long calls give their slot back between
// slices and ask again (Run), which puts them behind the other clients'
// turns. Streams and changes are bounded per client too
// (max_streams_per_client, half the changes).
#ifndef GEODESIC_SERVER_ADMISSION_H_
#define GEODESIC_SERVER_ADMISSION_H_

#include <atomic>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <string>

#include "absl/base/thread_annotations.h"
#include "absl/status/statusor.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"

namespace geodesic::server {

// The trailing metadata (and the absl::Status payload that becomes it) of a
// refusal a client should retry: how many milliseconds to wait first.
inline constexpr char kRetryAfterMsTrailer[] = "retry-after-ms";

struct AdmissionOptions {
  int max_inflight = 64;  // queries admitted, waiting or running
  int query_threads = 1;  // admitted queries running at once
  int max_streams = 32;   // streams open at once (watches, uploads)
  // Queries one client may have admitted at once (0: half of max_inflight,
  // at least 1), so that one client's flood leaves room for the others.
  int max_inflight_per_client = 0;
  // Streams one client may have open at once (0: half of max_streams, at
  // least 1): a client that opens streams and never reads them leaves the
  // other half to the others.
  int max_streams_per_client = 0;
  // Changes in progress at once (registrations, unloads, graph requests and
  // cancellations): they may wait on a mesh's name or read a file, each on a
  // thread of its own, so they are bounded apart from the quick control
  // calls (listing, get, health), which keep the rest of the control threads.
  // A client may have at most half of them (at least 1).
  int max_changes = 8;
  // Bytes the reservations of running queries must fit in, beside `held`;
  // 0: no memory reservation.
  uint64_t memory_limit = 0;
  // Bytes the limit already covers that no reservation accounts for
  // (meshes, graphs, landmarks).
  std::function<uint64_t()> held;
  // The part of `held` nothing frees to make room (meshes; graphs are
  // evicted): a query that cannot fit beside it is refused at once.
  std::function<uint64_t()> pinned;
  // Query scratch the engines keep, idle or in use: the part beyond the
  // scratch running queries reserved is idle and counts as held.
  std::function<uint64_t()> pooled_scratch;
};

class Admission {
 public:
  enum class Kind { kQuery, kRun, kStream, kChange, kAnswer };

  // Something admitted, given back when destroyed.
  class Ticket {
   public:
    Ticket() = default;
    Ticket(Ticket&& other) noexcept { *this = std::move(other); }
    Ticket& operator=(Ticket&& other) noexcept;
    ~Ticket() { Release(); }
    bool held() const { return owner_ != nullptr; }
    void Release();

   private:
    friend class Admission;
    Ticket(Admission* owner, Kind kind, std::string client, uint64_t answer, uint64_t scratch)
        : owner_(owner),
          kind_(kind),
          client_(std::move(client)),
          answer_(answer),
          scratch_(scratch) {}
    Admission* owner_ = nullptr;
    Kind kind_ = Kind::kQuery;
    std::string client_;
    uint64_t answer_ = 0, scratch_ = 0;
    absl::Time start_;
  };

  explicit Admission(AdmissionOptions options);
  Admission(const Admission&) = delete;
  Admission& operator=(const Admission&) = delete;

  // A query's place among the admitted. When max_inflight are admitted
  // already (or, while other clients have queries admitted, the client's
  // share of them), waits for a slot until `wait_until` (or `cancelled`),
  // then RESOURCE_EXHAUSTED "server overloaded: ..."; with `wait_until` past,
  // or max_inflight queries waiting already, refuses at once.
  absl::StatusOr<Ticket> AdmitQuery(const std::string& client = "",
                                    absl::Time wait_until = absl::InfinitePast(),
                                    const std::function<bool()>& cancelled = {});
  // A stream's place: RESOURCE_EXHAUSTED when max_streams are open, or the
  // client's share of them.
  absl::StatusOr<Ticket> OpenStream(const std::string& client = "");
  // A change's place: RESOURCE_EXHAUSTED when max_changes are in progress, or
  // the client's share of them.
  absl::StatusOr<Ticket> StartChange(const std::string& client = "");
  // An admitted query's turn to run: waits for one of the query_threads (the
  // client's turn among the waiting clients, and its own queries first come
  // first served) and for `answer_bytes + scratch_bytes` of memory
  // (with nothing running, the front query runs whatever evictable memory is
  // held, so that a cache filling the limit slows queries to one at a time,
  // not to none; answers kept for their clients are not evictable).
  // RESOURCE_EXHAUSTED at once if that much can never fit the limit, or when
  // `deadline` comes first (so the client reads a clean overload, not a
  // deadline); CANCELLED when `cancelled` says so.
  absl::StatusOr<Ticket> Run(uint64_t answer_bytes, uint64_t scratch_bytes, absl::Time deadline,
                             const std::function<bool()>& cancelled = {},
                             const std::string& client = "");
  // Whether a query of a client other than `client` waits to run: a slice
  // of long work then gives its slot back.
  bool OthersWaiting(const std::string& client) const;

  // Gives back `run`'s query thread but keeps its answer bytes reserved: for
  // a stream holding a computed block while it waits for its client, which
  // may take any time and needs no thread of the query_threads.
  Ticket KeepAnswer(Ticket run);
  // The answer bytes `kept` holds (KeepAnswer's), now held by `run`: for a
  // sliced call, whose partial answer stays counted while it waits for its
  // next slice, which then asks Run for its scratch alone.
  Ticket Adopt(Ticket run, Ticket kept);

  // The retry hint sent with a refusal: about how long the queries admitted
  // take to drain through the running slots, and at least `waited`, how
  // long the refused call waited for them.
  int64_t RetryAfterMs(absl::Duration waited = absl::ZeroDuration()) const;

  int admitted() const;
  // Queries waiting for admission (AdmitQuery), not yet admitted.
  int admission_waiting() const;
  int running() const;
  int waiting() const;
  int streams() const;
  uint64_t reserved_bytes() const;
  uint64_t refusals() const { return refusals_.load(std::memory_order_relaxed); }
  // Admission is full, or refused a call in the last second.
  bool overloaded() const;
  const AdmissionOptions& options() const { return options_; }

 private:
  void Release(const Ticket& t);
  // Memory the limit covers now, reservations included.
  uint64_t UsedLocked() const ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  // The part of it no eviction frees: pinned bytes and answers kept for
  // their clients.
  uint64_t UnevictableLocked() const ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  int64_t RetryAfterMsLocked(absl::Duration waited = absl::ZeroDuration()) const
      ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  absl::Status Refuse(const std::string& what, int64_t retry_after_ms);
  int InflightPerClient() const;
  struct AdmitWaiter;
  // Whether `client` may take a free admission slot: below its share, or
  // alone (no other client has queries admitted or waiting for admission).
  bool MayTakeSlotLocked(const std::string& client) const ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  void AdmitLocked(const std::string& client) ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  // Hands free admission slots to the waiters, the client with the fewest
  // admitted first (the oldest of its waiters).
  void GrantLocked() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  // Wakes the query whose turn it is to run, alone.
  void WakeNextLocked() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  // A slot of a pool bounded in all (`open` of `max`) and per client (the
  // client's `mine` of `max_mine`); `what` names the pool in refusals.
  absl::StatusOr<Ticket> OpenSlot(Kind kind, const std::string& client, int max, int max_mine,
                                  const char* what, const char* flag, const char* client_flag);
  // The waiting query whose turn it is: the oldest of the first client in
  // turn that runs less than its share of the slots (the first client in
  // turn if all run their share); 0 if none waits.
  uint64_t NextLocked() const ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  // Takes query `number` of `client` out of the waiting ones.
  void LeaveQueueLocked(const std::string& client, uint64_t number)
      ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  // Forgets a client that has nothing admitted, running or waiting.
  void ForgetIfIdleLocked(const std::string& client) ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);

  const AdmissionOptions options_;
  mutable absl::Mutex mu_;
  // Queries waiting for admission, in arrival order, and those admitted and
  // waiting to run, by number: each waits on a condition of its own.
  std::deque<AdmitWaiter*> admit_waiters_ ABSL_GUARDED_BY(mu_);
  std::map<uint64_t, absl::CondVar*> run_waiters_ ABSL_GUARDED_BY(mu_);
  int admitted_ ABSL_GUARDED_BY(mu_) = 0;
  int running_ ABSL_GUARDED_BY(mu_) = 0;
  int streams_ ABSL_GUARDED_BY(mu_) = 0;
  int changes_ ABSL_GUARDED_BY(mu_) = 0;
  uint64_t reserved_answer_ ABSL_GUARDED_BY(mu_) = 0;
  uint64_t reserved_scratch_ ABSL_GUARDED_BY(mu_) = 0;
  struct Client {
    int admitted = 0;
    int running = 0;
    int streams = 0;
    int changes = 0;
    int admit_waiting = 0;         // its queries waiting for admission
    std::deque<uint64_t> waiting;  // its admitted queries' numbers waiting to run, in order
  };
  std::map<std::string, Client> clients_ ABSL_GUARDED_BY(mu_);
  // The clients with queries waiting, in the order their turns come.
  std::deque<std::string> turns_ ABSL_GUARDED_BY(mu_);
  int waiting_ ABSL_GUARDED_BY(mu_) = 0;
  uint64_t next_number_ ABSL_GUARDED_BY(mu_) = 1;
  // Mean seconds a query runs (exponentially weighted), for the retry hint.
  double mean_run_seconds_ ABSL_GUARDED_BY(mu_) = 0.01;
  absl::Time last_refusal_ ABSL_GUARDED_BY(mu_) = absl::InfinitePast();
  std::atomic<uint64_t> refusals_{0};
};

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_ADMISSION_H_
