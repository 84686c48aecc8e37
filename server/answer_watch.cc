#include "server/answer_watch.h"

#include <optional>
#include <string>

#include "absl/strings/str_format.h"
#include "grpcpp/server_context.h"

namespace geodesic::server {
namespace {

using grpc::experimental::InterceptionHookPoints;

class AnswerWatch : public grpc::experimental::Interceptor {
 public:
  AnswerWatch(grpc::experimental::ServerRpcInfo* info, StreamWatchdog* watchdog,
              const std::function<void(const grpc::ServerContextBase*)>* sent)
      : info_(info), ctx_(info->server_context()), watchdog_(watchdog), sent_(sent) {}
  // A call that ends without its send hook (cancelled first) is done too.
  ~AnswerWatch() override { (*sent_)(ctx_); }

  void Intercept(grpc::experimental::InterceptorBatchMethods* methods) override {
    if (methods->QueryInterceptionHookPoint(InterceptionHookPoints::PRE_SEND_MESSAGE)) {
      grpc::ServerContextBase* ctx = info_->server_context();
      watch_.emplace(watchdog_->AddWaiting(
          absl::StrFormat("the answer of %s to %s", info_->method(), ctx->peer()),
          [ctx] { ctx->TryCancel(); }));
    }
    // Sent, or failed: the call goes on to its end without waiting on the
    // client, and the watch must not outlive the call it would cancel.
    if (methods->QueryInterceptionHookPoint(InterceptionHookPoints::POST_SEND_MESSAGE)) {
      watch_.reset();
      (*sent_)(ctx_);
    }
    methods->Proceed();
  }

 private:
  grpc::experimental::ServerRpcInfo* info_;
  const grpc::ServerContextBase* ctx_;
  StreamWatchdog* watchdog_;
  const std::function<void(const grpc::ServerContextBase*)>* sent_;
  std::optional<StreamWatchdog::Watch> watch_;
};

}  // namespace

grpc::experimental::Interceptor* AnswerWatchFactory::CreateServerInterceptor(
    grpc::experimental::ServerRpcInfo* info) {
  if (info->type() != grpc::experimental::ServerRpcInfo::Type::UNARY) return nullptr;
  return new AnswerWatch(info, watchdog_, &sent_);
}

}  // namespace geodesic::server
