#include "server/limits/client_key.h"

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

using ::testing::HasSubstr;

// A service whose ListMeshes records who called, as `identity` tells.
class RecordsCallers final : public v1::Geodesic::Service {
 public:
  grpc::Status ListMeshes(grpc::ServerContext* ctx, const v1::ListMeshesRequest*,
                          v1::ListMeshesResponse*) override {
    absl::MutexLock lock(&mu_);
    last_ = identity_.Key(*ctx);
    authenticated_ = identity_.Authenticate(*ctx);
    return grpc::Status::OK;
  }
  void set_identity(ClientIdentity identity) {
    absl::MutexLock lock(&mu_);
    identity_ = std::move(identity);
  }
  std::string last() {
    absl::MutexLock lock(&mu_);
    return last_;
  }
  absl::Status authenticated() {
    absl::MutexLock lock(&mu_);
    return authenticated_;
  }

 private:
  absl::Mutex mu_;
  ClientIdentity identity_;
  std::string last_;
  absl::Status authenticated_;
};

using Metadata = std::vector<std::pair<std::string, std::string>>;

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
  std::string KeyOf(v1::Geodesic::Stub& stub, const Metadata& metadata) {
    grpc::ClientContext ctx;
    for (const auto& [k, v] : metadata) ctx.AddMetadata(k, v);
    v1::ListMeshesResponse resp;
    const grpc::Status status = stub.ListMeshes(&ctx, {}, &resp);
    EXPECT_TRUE(status.ok()) << status.error_message();
    return service_.last();
  }
  // Whether a call with `metadata` authenticates.
  absl::Status AuthenticationOf(const Metadata& metadata) {
    KeyOf(*tcp_, metadata);
    return service_.authenticated();
  }

  RecordsCallers service_;
  std::unique_ptr<grpc::Server> server_;
  std::unique_ptr<v1::Geodesic::Stub> tcp_, inproc_;
};

TEST_F(ClientKeyTest, WithoutTokensAHostIsOneClientWhateverItSends) {
  const std::string anonymous = KeyOf(*tcp_, {});
  EXPECT_EQ(anonymous, "ipv4:127.0.0.1");
  // Another connection from the host is the same client.
  EXPECT_EQ(KeyOf(*tcp_, {}), anonymous);
  // Made-up tokens mint no new clients.
  EXPECT_EQ(KeyOf(*tcp_, {{"authorization", "Bearer a"}}), anonymous);
  EXPECT_EQ(KeyOf(*tcp_, {{"authorization", "Bearer b"}}), anonymous);
  EXPECT_TRUE(AuthenticationOf({{"authorization", "Bearer b"}}).ok());
}

TEST_F(ClientKeyTest, WithTokensEachTokenThatAuthenticatesIsAClient) {
  service_.set_identity(ClientIdentity({"alpha", "beta"}));
  const std::string a = KeyOf(*tcp_, {{"authorization", "Bearer alpha"}});
  const std::string b = KeyOf(*tcp_, {{"authorization", "Bearer beta"}});
  EXPECT_EQ(a, "ipv4:127.0.0.1 token 0");
  EXPECT_EQ(b, "ipv4:127.0.0.1 token 1");
  EXPECT_TRUE(AuthenticationOf({{"authorization", "Bearer beta"}}).ok());
  // A wrong token, none, or a forged one beside the real one: refused, and
  // no key names a token it did not authenticate with.
  EXPECT_EQ(AuthenticationOf({{"authorization", "Bearer gamma"}}).code(),
            absl::StatusCode::kUnauthenticated);
  EXPECT_EQ(AuthenticationOf({}).code(), absl::StatusCode::kUnauthenticated);
  const Metadata forged = {{"authorization", "Bearer random"}, {"authorization", "Bearer alpha"}};
  const absl::Status twice = AuthenticationOf(forged);
  EXPECT_EQ(twice.code(), absl::StatusCode::kUnauthenticated);
  EXPECT_THAT(std::string(twice.message()), HasSubstr("exactly one"));
  EXPECT_EQ(KeyOf(*tcp_, forged), "ipv4:127.0.0.1");
  EXPECT_EQ(KeyOf(*tcp_, {{"authorization", "Bearer gamma"}}), "ipv4:127.0.0.1");
}

TEST_F(ClientKeyTest, TheHttpClientsAddressCountsOnlyWithThisProcesssSecret) {
  // A remote gRPC client cannot pose as another by sending the gateway's metadata.
  EXPECT_EQ(KeyOf(*tcp_, {{kHttpClientMetadata, "203.0.113.9"}}), "ipv4:127.0.0.1");
  EXPECT_EQ(KeyOf(*tcp_, {{kHttpClientMetadata, "guess 203.0.113.9"}}), "ipv4:127.0.0.1");
  // The gateway's calls, on the in-process channel, are their HTTP clients.
  EXPECT_EQ(KeyOf(*inproc_, {{kHttpClientMetadata, HttpClientValue("203.0.113.9")}}),
            "http 203.0.113.9");
  EXPECT_EQ(KeyOf(*inproc_, {{kHttpClientMetadata, HttpClientValue("::1")}}), "http ::1");
  service_.set_identity(ClientIdentity({"t"}));
  EXPECT_EQ(KeyOf(*inproc_,
                  {{kHttpClientMetadata, HttpClientValue("::1")}, {"authorization", "Bearer t"}}),
            "http ::1 token 0");
}

}  // namespace
}  // namespace geodesic::server
