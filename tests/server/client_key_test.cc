#include "server/client_key.h"

#include <grpcpp/grpcpp.h>

#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "absl/synchronization/mutex.h"
#include "geodesic/v1/geodesic.grpc.pb.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"

namespace geodesic::server {
namespace {

using ::testing::StartsWith;

// A service whose ListMeshes records who called.
class RecordsCallers final : public v1::Geodesic::Service {
 public:
  grpc::Status ListMeshes(grpc::ServerContext* ctx, const v1::ListMeshesRequest*,
                          v1::ListMeshesResponse*) override {
    absl::MutexLock lock(&mu_);
    last_ = ClientKey(*ctx);
    return grpc::Status::OK;
  }
  std::string last() {
    absl::MutexLock lock(&mu_);
    return last_;
  }

 private:
  absl::Mutex mu_;
  std::string last_;
};

class ClientKeyTest : public ::testing::Test {
 protected:
  void SetUp() override {
    grpc::ServerBuilder builder;
    int port = 0;
    builder.AddListeningPort("127.0.0.1:0", grpc::InsecureServerCredentials(), &port);
    builder.RegisterService(&service_);
    server_ = builder.BuildAndStart();
    ASSERT_NE(port, 0);
    tcp_ = v1::Geodesic::NewStub(grpc::CreateChannel("127.0.0.1:" + std::to_string(port),
                                                     grpc::InsecureChannelCredentials()));
    inproc_ = v1::Geodesic::NewStub(server_->InProcessChannel(grpc::ChannelArguments()));
  }
  void TearDown() override { server_->Shutdown(); }

  // The key of one call through `stub` with `metadata`.
  std::string KeyOf(v1::Geodesic::Stub& stub,
                    const std::vector<std::pair<std::string, std::string>>& metadata) {
    grpc::ClientContext ctx;
    for (const auto& [k, v] : metadata) ctx.AddMetadata(k, v);
    v1::ListMeshesResponse resp;
    const grpc::Status status = stub.ListMeshes(&ctx, {}, &resp);
    EXPECT_TRUE(status.ok()) << status.error_message();
    return service_.last();
  }

  RecordsCallers service_;
  std::unique_ptr<grpc::Server> server_;
  std::unique_ptr<v1::Geodesic::Stub> tcp_, inproc_;
};

TEST_F(ClientKeyTest, TheAddressWithoutItsPortAndTheTokenTellClientsApart) {
  const std::string anonymous = KeyOf(*tcp_, {});
  EXPECT_EQ(anonymous, "ipv4:127.0.0.1");
  // Another connection from the host is the same client.
  EXPECT_EQ(KeyOf(*tcp_, {}), anonymous);
  const std::string a = KeyOf(*tcp_, {{"authorization", "Bearer a"}});
  const std::string b = KeyOf(*tcp_, {{"authorization", "Bearer b"}});
  EXPECT_THAT(a, StartsWith(anonymous));
  EXPECT_THAT(b, StartsWith(anonymous));
  EXPECT_NE(a, b);
  EXPECT_NE(a, anonymous);
}

TEST_F(ClientKeyTest, TheHttpClientsAddressCountsOnlyWithThisProcesssSecret) {
  // A remote gRPC client cannot pose as another by sending the gateway's metadata.
  EXPECT_EQ(KeyOf(*tcp_, {{kHttpClientMetadata, "203.0.113.9"}}), "ipv4:127.0.0.1");
  EXPECT_EQ(KeyOf(*tcp_, {{kHttpClientMetadata, "guess 203.0.113.9"}}), "ipv4:127.0.0.1");
  // The gateway's calls, on the in-process channel, are their HTTP clients.
  EXPECT_EQ(KeyOf(*inproc_, {{kHttpClientMetadata, HttpClientValue("203.0.113.9")}}),
            "http 203.0.113.9");
  EXPECT_EQ(KeyOf(*inproc_, {{kHttpClientMetadata, HttpClientValue("::1")}}), "http ::1");
  EXPECT_EQ(KeyOf(*inproc_,
                  {{kHttpClientMetadata, HttpClientValue("::1")}, {"authorization", "Bearer t"}}),
            "http ::1 token t");
}

}  // namespace
}  // namespace geodesic::server
