// The pipeline's table of RPCs (server/grpc/call.h) against the service the
// proto declares: every RPC classified once, and the classes as admission
// relies on them.
#include "server/grpc/call.h"

#include <set>
#include <string>

#include "geodesic/v1/geodesic.pb.h"
#include "gtest/gtest.h"

namespace geodesic::server {
namespace {

TEST(CallTest, TheTableListsEveryRpcOfTheServiceOnce) {
  const auto* service = v1::DistanceRequest::descriptor()->file()->FindServiceByName("Geodesic");
  ASSERT_NE(service, nullptr);
  ASSERT_GT(service->method_count(), 0);
  std::set<std::string> declared, listed;
  for (int i = 0; i < service->method_count(); ++i) {
    const auto* method = service->method(i);
    declared.insert(method->name());
    const RpcKind& kind = RpcNamed(method->name());
    // A call that streams its answer or its request holds a stream slot.
    EXPECT_EQ(kind.stream, method->server_streaming() || method->client_streaming())
        << method->name();
    EXPECT_FALSE(kind.query && kind.stream) << method->name() << ": admitted twice";
  }
  for (const RpcKind& kind : Rpcs()) {
    EXPECT_TRUE(listed.insert(kind.name).second) << kind.name << " is listed twice";
  }
  EXPECT_EQ(declared, listed);
}

TEST(CallTest, QueriesAndChangesAreWhatAdmissionBounds) {
  EXPECT_TRUE(RpcNamed("Distance").query);
  EXPECT_TRUE(RpcNamed("SamplePoints").query);
  EXPECT_FALSE(RpcNamed("GetGraph").query);
  EXPECT_TRUE(RpcNamed("RegisterMesh").change);
  EXPECT_TRUE(RpcNamed("CancelGraph").change);
  EXPECT_FALSE(RpcNamed("ListMeshes").change);
}

}  // namespace
}  // namespace geodesic::server
