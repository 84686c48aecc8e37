// Unary answers nobody reads. The synchronous server sends a unary call's
// answer on the thread that computed it, which waits until the client has
// taken it all: a client that stops reading (a stopped process, a full
// socket) would hold that thread for as long as its connection lives, beyond
// anything admission counts. This interceptor watches each unary answer from
// the moment it is handed to gRPC until it is sent, and the StreamWatchdog
// cancels one not taken within --idle-seconds, which gives the thread back.
// Streams watch their own messages (GeodesicService::WatchStream).
#ifndef GEODESIC_SERVER_ANSWER_WATCH_H_
#define GEODESIC_SERVER_ANSWER_WATCH_H_

#include <memory>

#include "grpcpp/support/server_interceptor.h"
#include "server/limits/stream_watchdog.h"

namespace geodesic::server {

class AnswerWatchFactory : public grpc::experimental::ServerInterceptorFactoryInterface {
 public:
  explicit AnswerWatchFactory(StreamWatchdog* watchdog) : watchdog_(watchdog) {}
  grpc::experimental::Interceptor* CreateServerInterceptor(
      grpc::experimental::ServerRpcInfo* info) override;

 private:
  StreamWatchdog* watchdog_;
};

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_ANSWER_WATCH_H_
