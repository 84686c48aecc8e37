#include "server/limits/answer_watch.h"

#include <optional>
#include <string>

#include "absl/strings/str_format.h"
#include "grpcpp/server_context.h"

namespace geodesic::server {
namespace {

using grpc::experimental::InterceptionHookPoints;

class AnswerWatch : public grpc::experimental::Interceptor {
 public:
  AnswerWatch(grpc::experimental::ServerRpcInfo* info, StreamWatchdog* watchdog)
      : info_(info), watchdog_(watchdog) {}

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
    }
    methods->Proceed();
  }

 private:
  grpc::experimental::ServerRpcInfo* info_;
  StreamWatchdog* watchdog_;
  std::optional<StreamWatchdog::Watch> watch_;
};

}  // namespace

grpc::experimental::Interceptor* AnswerWatchFactory::CreateServerInterceptor(
    grpc::experimental::ServerRpcInfo* info) {
  if (info->type() != grpc::experimental::ServerRpcInfo::Type::UNARY) return nullptr;
  return new AnswerWatch(info, watchdog_);
}

}  // namespace geodesic::server
