// grpc.reflection.v1.ServerReflection beside gRPC's v1alpha. gRPC 1.51's
// reflection plugin serves only grpc.reflection.v1alpha, and tools built on
// newer gRPC (grpcurl, Postman, grpcui) ask for v1 and fail on UNIMPLEMENTED.
// The protocol is the same in both versions; this service answers it from
// the protobuf descriptors linked into the daemon, as v1alpha does.
//
// Like health and v1alpha it is a service of its own, outside
// GeodesicService's bearer-token check: a tool learns the API without a
// secret, and every call it then makes to geodesic.v1 needs one. Being
// open, its streams use gRPC's callback API: an idle one holds no thread of
// the server's quota (v1alpha's synchronous streams each hold one).
#ifndef GEODESIC_SERVER_REFLECTION_V1_H_
#define GEODESIC_SERVER_REFLECTION_V1_H_

#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "google/protobuf/descriptor.h"
#include "grpc/reflection/v1/reflection.grpc.pb.h"
#include "grpcpp/grpcpp.h"

namespace geodesic::server {

class ReflectionV1Service final : public grpc::reflection::v1::ServerReflection::CallbackService {
 public:
  using Request = grpc::reflection::v1::ServerReflectionRequest;
  using Response = grpc::reflection::v1::ServerReflectionResponse;

  // Answers from `pool`: by default the descriptors compiled into this
  // program (geodesic.v1, grpc.health.v1, both reflections).
  explicit ReflectionV1Service(const google::protobuf::DescriptorPool* pool =
                                   google::protobuf::DescriptorPool::generated_pool());

  // The server's list of service names, which it fills while it starts (the
  // health service last, in Server::Start): read at each list_services, so
  // it must outlive this service, as the server does. Unset: none.
  void SetServiceList(const std::vector<std::string>* services) { services_ = services; }

  // Each request on the stream answered in turn; one that cannot be answered
  // gets an error_response and the stream goes on until the client closes
  // it.
  grpc::ServerBidiReactor<Request, Response>* ServerReflectionInfo(
      grpc::CallbackServerContext* ctx) override;

  // One request's response, echoing host and request as the protocol asks.
  Response Answer(const Request& request) const;

 private:
  absl::StatusOr<grpc::reflection::v1::FileDescriptorResponse> FileByName(
      const std::string& name) const;
  absl::StatusOr<grpc::reflection::v1::FileDescriptorResponse> FileContainingSymbol(
      const std::string& symbol) const;
  absl::StatusOr<grpc::reflection::v1::FileDescriptorResponse> FileContainingExtension(
      const grpc::reflection::v1::ExtensionRequest& request) const;
  absl::StatusOr<grpc::reflection::v1::ExtensionNumberResponse> ExtensionNumbers(
      const std::string& type) const;
  grpc::reflection::v1::ListServiceResponse ListServices() const;

  const google::protobuf::DescriptorPool* pool_;
  const std::vector<std::string>* services_ = nullptr;
};

// Serves a ReflectionV1Service on the server `builder` builds, listing every
// service that server registers: the builder's own, and those gRPC adds as
// it builds and starts (health, reflection v1alpha, this one). Call before
// BuildAndStart.
void AddReflectionV1(grpc::ServerBuilder& builder);

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_REFLECTION_V1_H_
