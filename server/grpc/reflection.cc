#include "server/grpc/reflection.h"

#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "absl/container/flat_hash_set.h"
#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "google/protobuf/descriptor.pb.h"
#include "grpc/health/v1/health.pb.h"
#include "grpcpp/impl/server_builder_option.h"
#include "grpcpp/impl/server_builder_plugin.h"
#include "grpcpp/impl/server_initializer.h"
#include "server/base/echo.h"

namespace geodesic::server {
namespace {

// `file` and every file it imports, transitively, each once (`seen`), the
// file itself first: a client reads the first as the answer and the rest as
// what it needs to build it.
template <typename Files>
void AddFileAndImports(const google::protobuf::FileDescriptor* file,
                       absl::flat_hash_set<std::string>* seen, Files* out) {
  if (!seen->insert(file->name()).second) return;
  google::protobuf::FileDescriptorProto proto;
  file->CopyTo(&proto);
  proto.SerializeToString(out->add_file_descriptor_proto());
  for (int i = 0; i < file->dependency_count(); ++i) {
    AddFileAndImports(file->dependency(i), seen, out);
  }
}

template <typename Files>
Files FileAndImports(const google::protobuf::FileDescriptor* file) {
  absl::flat_hash_set<std::string> seen;
  Files out;
  AddFileAndImports(file, &seen, &out);
  return out;
}

// One ServerReflectionInfo stream: read a request, write its answer, read
// the next; one operation at a time, and no thread held between them.
template <typename Api>
class ReflectionStream final
    : public grpc::ServerBidiReactor<typename Api::Request, typename Api::Response> {
 public:
  explicit ReflectionStream(const ReflectionService<Api>* service) : service_(service) {
    this->StartRead(&request_);
  }
  void OnReadDone(bool ok) override {
    // Not ok: the client closed its side (or the call ended).
    if (!ok) return this->Finish(grpc::Status::OK);
    response_ = service_->Answer(request_);
    this->StartWrite(&response_);
  }
  void OnWriteDone(bool ok) override {
    if (!ok) return this->Finish(grpc::Status(grpc::StatusCode::CANCELLED, "the client went away"));
    this->StartRead(&request_);
  }
  void OnDone() override { delete this; }

 private:
  const ReflectionService<Api>* service_;
  typename Api::Request request_;
  typename Api::Response response_;
};

// Builds the server with both versions on it and, once the server has
// registered every service, hands them the server's list of them.
class ReflectionPlugin final : public grpc::ServerBuilderPlugin {
 public:
  std::string name() override { return "geodesic_reflection"; }
  void InitServer(grpc::ServerInitializer* si) override {
    si->RegisterService(v1_);
    si->RegisterService(v1alpha_);
  }
  void Finish(grpc::ServerInitializer* si) override {
    v1_->SetServiceList(si->GetServiceList());
    v1alpha_->SetServiceList(si->GetServiceList());
  }
  void ChangeArguments(const std::string&, void*) override {}

 private:
  std::shared_ptr<ReflectionService<ReflectionV1>> v1_ =
      std::make_shared<ReflectionService<ReflectionV1>>();
  std::shared_ptr<ReflectionService<ReflectionV1Alpha>> v1alpha_ =
      std::make_shared<ReflectionService<ReflectionV1Alpha>>();
};

// Adds the plugin to one builder's plugins (gRPC's own way,
// InternalAddPluginFactory, would add it to every server of the process).
class ReflectionOption final : public grpc::ServerBuilderOption {
 public:
  void UpdateArguments(grpc::ChannelArguments*) override {}
  void UpdatePlugins(std::vector<std::unique_ptr<grpc::ServerBuilderPlugin>>* plugins) override {
    plugins->push_back(std::make_unique<ReflectionPlugin>());
  }
};

}  // namespace

template <typename Api>
ReflectionService<Api>::ReflectionService(const google::protobuf::DescriptorPool* pool)
    : pool_(pool) {
  // The daemon calls nothing of the health messages (gRPC serves health with
  // its own): naming one here links their descriptors in, so that a tool can
  // describe grpc.health.v1.Health as well as list it.
  grpc::health::v1::HealthCheckRequest::descriptor();
}

template <typename Api>
grpc::ServerBidiReactor<typename Api::Request, typename Api::Response>*
ReflectionService<Api>::ServerReflectionInfo(grpc::CallbackServerContext*) {
  return new ReflectionStream<Api>(this);
}

template <typename Api>
typename Api::Response ReflectionService<Api>::Answer(const Request& request) const {
  Response response;
  response.set_valid_host(request.host());
  *response.mutable_original_request() = request;
  absl::Status status;
  // Puts an answer in its place in the response, or keeps its error.
  auto put = [&status](auto answer, auto* place) {
    if (answer.ok()) *place = *std::move(answer);
    status = answer.status();
  };
  switch (request.message_request_case()) {
    case Request::kFileByFilename:
      put(FileByName(request.file_by_filename()), response.mutable_file_descriptor_response());
      break;
    case Request::kFileContainingSymbol:
      put(FileContainingSymbol(request.file_containing_symbol()),
          response.mutable_file_descriptor_response());
      break;
    case Request::kFileContainingExtension:
      put(FileContainingExtension(request.file_containing_extension()),
          response.mutable_file_descriptor_response());
      break;
    case Request::kAllExtensionNumbersOfType:
      put(ExtensionNumbers(request.all_extension_numbers_of_type()),
          response.mutable_all_extension_numbers_response());
      break;
    case Request::kListServices:
      *response.mutable_list_services_response() = ListServices();
      break;
    case Request::MESSAGE_REQUEST_NOT_SET:
      status = absl::InvalidArgumentError("the request names nothing to reflect on");
      break;
  }
  if (!status.ok()) {
    // absl's codes are gRPC's, number for number.
    response.mutable_error_response()->set_error_code(static_cast<int>(status.code()));
    response.mutable_error_response()->set_error_message(std::string(status.message()));
  }
  return response;
}

template <typename Api>
absl::StatusOr<typename Api::Files> ReflectionService<Api>::FileByName(
    const std::string& name) const {
  const google::protobuf::FileDescriptor* file = pool_->FindFileByName(name);
  if (!file) return absl::NotFoundError(absl::StrFormat("file '%s' not found", Echo(name)));
  return FileAndImports<typename Api::Files>(file);
}

template <typename Api>
absl::StatusOr<typename Api::Files> ReflectionService<Api>::FileContainingSymbol(
    const std::string& symbol) const {
  const google::protobuf::FileDescriptor* file = pool_->FindFileContainingSymbol(symbol);
  if (!file) return absl::NotFoundError(absl::StrFormat("symbol '%s' not found", Echo(symbol)));
  return FileAndImports<typename Api::Files>(file);
}

template <typename Api>
absl::StatusOr<typename Api::Files> ReflectionService<Api>::FileContainingExtension(
    const typename Api::ExtensionRequest& request) const {
  const auto* type = pool_->FindMessageTypeByName(request.containing_type());
  if (!type) {
    return absl::NotFoundError(
        absl::StrFormat("type '%s' not found", Echo(request.containing_type())));
  }
  const auto* extension = pool_->FindExtensionByNumber(type, request.extension_number());
  if (!extension) {
    return absl::NotFoundError(absl::StrFormat("extension %d of '%s' not found",
                                               request.extension_number(), type->full_name()));
  }
  return FileAndImports<typename Api::Files>(extension->file());
}

template <typename Api>
absl::StatusOr<typename Api::ExtensionNumbers> ReflectionService<Api>::ExtensionNumbers(
    const std::string& type_name) const {
  const auto* type = pool_->FindMessageTypeByName(type_name);
  if (!type) return absl::NotFoundError(absl::StrFormat("type '%s' not found", Echo(type_name)));
  std::vector<const google::protobuf::FieldDescriptor*> extensions;
  pool_->FindAllExtensions(type, &extensions);
  typename Api::ExtensionNumbers out;
  out.set_base_type_name(type->full_name());
  for (const auto* extension : extensions) out.add_extension_number(extension->number());
  return out;
}

template <typename Api>
typename Api::Services ReflectionService<Api>::ListServices() const {
  typename Api::Services out;
  if (services_) {
    for (const std::string& name : *services_) out.add_service()->set_name(name);
  }
  return out;
}

template class ReflectionService<ReflectionV1>;
template class ReflectionService<ReflectionV1Alpha>;

void AddReflection(grpc::ServerBuilder& builder) {
  builder.SetOption(std::make_unique<ReflectionOption>());
}

}  // namespace geodesic::server
