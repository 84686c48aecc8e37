// gRPC server reflection, grpc.reflection.v1 and v1alpha, answered from the
// protobuf descriptors linked into the daemon. gRPC 1.51's reflection plugin
// serves only v1alpha, and tools built on newer gRPC (grpcurl, Postman,
// grpcui) ask for v1 and fail on UNIMPLEMENTED; the plugin also holds a
// server thread for each open stream, so that a few hundred idle streams,
// which need no token, took every thread and locked every call out. The
// protocol is the same in both versions (proto/CMakeLists.txt makes v1alpha's
// messages from v1's): one service template serves both.
//
// Like health it is a service of its own, outside GeodesicService's
// bearer-token check: a tool learns the API without a secret, and every call
// it then makes to geodesic.v1 needs one. Being open, its streams use gRPC's
// callback API: an idle one holds no thread of the server's quota.
#ifndef GEODESIC_SERVER_REFLECTION_H_
#define GEODESIC_SERVER_REFLECTION_H_

#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "google/protobuf/descriptor.h"
#include "grpc/reflection/v1/reflection.grpc.pb.h"
#include "grpc/reflection/v1alpha/reflection.grpc.pb.h"
#include "grpcpp/grpcpp.h"

namespace geodesic::server {

// The generated types of one version of the protocol.
template <typename Service_, typename Request_, typename Response_, typename Files_,
          typename ExtensionRequest_, typename ExtensionNumbers_, typename Services_>
struct ReflectionApi {
  using Service = Service_;
  using Request = Request_;
  using Response = Response_;
  using Files = Files_;  // FileDescriptorResponse
  using ExtensionRequest = ExtensionRequest_;
  using ExtensionNumbers = ExtensionNumbers_;  // ExtensionNumberResponse
  using Services = Services_;                  // ListServiceResponse
};

namespace reflection_v1 = grpc::reflection::v1;
namespace reflection_v1alpha = grpc::reflection::v1alpha;
using ReflectionV1 =
    ReflectionApi<reflection_v1::ServerReflection, reflection_v1::ServerReflectionRequest,
                  reflection_v1::ServerReflectionResponse, reflection_v1::FileDescriptorResponse,
                  reflection_v1::ExtensionRequest, reflection_v1::ExtensionNumberResponse,
                  reflection_v1::ListServiceResponse>;
using ReflectionV1Alpha =
    ReflectionApi<reflection_v1alpha::ServerReflection, reflection_v1alpha::ServerReflectionRequest,
                  reflection_v1alpha::ServerReflectionResponse,
                  reflection_v1alpha::FileDescriptorResponse, reflection_v1alpha::ExtensionRequest,
                  reflection_v1alpha::ExtensionNumberResponse,
                  reflection_v1alpha::ListServiceResponse>;

template <typename Api>
class ReflectionService final : public Api::Service::CallbackService {
 public:
  using Request = typename Api::Request;
  using Response = typename Api::Response;

  // Answers from `pool`: by default the descriptors compiled into this
  // program (geodesic.v1, grpc.health.v1, both reflections).
  explicit ReflectionService(const google::protobuf::DescriptorPool* pool =
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
  absl::StatusOr<typename Api::Files> FileByName(const std::string& name) const;
  absl::StatusOr<typename Api::Files> FileContainingSymbol(const std::string& symbol) const;
  absl::StatusOr<typename Api::Files> FileContainingExtension(
      const typename Api::ExtensionRequest& request) const;
  absl::StatusOr<typename Api::ExtensionNumbers> ExtensionNumbers(const std::string& type) const;
  typename Api::Services ListServices() const;

  const google::protobuf::DescriptorPool* pool_;
  const std::vector<std::string>* services_ = nullptr;
};

extern template class ReflectionService<ReflectionV1>;
extern template class ReflectionService<ReflectionV1Alpha>;

// Serves reflection v1 and v1alpha on the server `builder` builds, each
// listing every service that server registers: the builder's own, and those
// gRPC adds as it builds and starts (health, these two). Call before
// BuildAndStart.
void AddReflection(grpc::ServerBuilder& builder);

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_REFLECTION_H_
