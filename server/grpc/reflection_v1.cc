#include "server/grpc/reflection_v1.h"

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

namespace rv1 = grpc::reflection::v1;

// `file` and every file it imports, transitively, each once (`seen`), the
// file itself first: a client reads the first as the answer and the rest as
// what it needs to build it.
void AddFileAndImports(const google::protobuf::FileDescriptor* file,
                       absl::flat_hash_set<std::string>* seen, rv1::FileDescriptorResponse* out) {
  if (!seen->insert(file->name()).second) return;
  google::protobuf::FileDescriptorProto proto;
  file->CopyTo(&proto);
  proto.SerializeToString(out->add_file_descriptor_proto());
  for (int i = 0; i < file->dependency_count(); ++i) {
    AddFileAndImports(file->dependency(i), seen, out);
  }
}

rv1::FileDescriptorResponse FileAndImports(const google::protobuf::FileDescriptor* file) {
  absl::flat_hash_set<std::string> seen;
  rv1::FileDescriptorResponse out;
  AddFileAndImports(file, &seen, &out);
  return out;
}

// One ServerReflectionInfo stream: read a request, write its answer, read
// the next; one operation at a time, and no thread held between them.
class ReflectionStream final
    : public grpc::ServerBidiReactor<ReflectionV1Service::Request, ReflectionV1Service::Response> {
 public:
  explicit ReflectionStream(const ReflectionV1Service* service) : service_(service) {
    StartRead(&request_);
  }
  void OnReadDone(bool ok) override {
    // Not ok: the client closed its side (or the call ended).
    if (!ok) return Finish(grpc::Status::OK);
    response_ = service_->Answer(request_);
    StartWrite(&response_);
  }
  void OnWriteDone(bool ok) override {
    if (!ok) return Finish(grpc::Status(grpc::StatusCode::CANCELLED, "the client went away"));
    StartRead(&request_);
  }
  void OnDone() override { delete this; }

 private:
  const ReflectionV1Service* service_;
  ReflectionV1Service::Request request_;
  ReflectionV1Service::Response response_;
};

// Builds the server with the service on it and, once the server has
// registered every service, hands the service the server's list of them.
class ReflectionV1Plugin final : public grpc::ServerBuilderPlugin {
 public:
  std::string name() override { return "geodesic_reflection_v1"; }
  void InitServer(grpc::ServerInitializer* si) override { si->RegisterService(service_); }
  void Finish(grpc::ServerInitializer* si) override {
    service_->SetServiceList(si->GetServiceList());
  }
  void ChangeArguments(const std::string&, void*) override {}

 private:
  std::shared_ptr<ReflectionV1Service> service_ = std::make_shared<ReflectionV1Service>();
};

// Adds the plugin to one builder's plugins (gRPC's own way,
// InternalAddPluginFactory, would add it to every server of the process).
class ReflectionV1Option final : public grpc::ServerBuilderOption {
 public:
  void UpdateArguments(grpc::ChannelArguments*) override {}
  void UpdatePlugins(std::vector<std::unique_ptr<grpc::ServerBuilderPlugin>>* plugins) override {
    plugins->push_back(std::make_unique<ReflectionV1Plugin>());
  }
};

}  // namespace

ReflectionV1Service::ReflectionV1Service(const google::protobuf::DescriptorPool* pool)
    : pool_(pool) {
  // The daemon calls nothing of the health messages (gRPC serves health with
  // its own): naming one here links their descriptors in, so that a tool can
  // describe grpc.health.v1.Health as well as list it.
  grpc::health::v1::HealthCheckRequest::descriptor();
}

grpc::ServerBidiReactor<ReflectionV1Service::Request, ReflectionV1Service::Response>*
ReflectionV1Service::ServerReflectionInfo(grpc::CallbackServerContext*) {
  return new ReflectionStream(this);
}

ReflectionV1Service::Response ReflectionV1Service::Answer(const Request& request) const {
  Response response;
  response.set_valid_host(request.host());
  *response.mutable_original_request() = request;
  absl::Status status;
  switch (request.message_request_case()) {
    case Request::kFileByFilename: {
      auto files = FileByName(request.file_by_filename());
      if (files.ok()) *response.mutable_file_descriptor_response() = *std::move(files);
      status = files.status();
      break;
    }
    case Request::kFileContainingSymbol: {
      auto files = FileContainingSymbol(request.file_containing_symbol());
      if (files.ok()) *response.mutable_file_descriptor_response() = *std::move(files);
      status = files.status();
      break;
    }
    case Request::kFileContainingExtension: {
      auto files = FileContainingExtension(request.file_containing_extension());
      if (files.ok()) *response.mutable_file_descriptor_response() = *std::move(files);
      status = files.status();
      break;
    }
    case Request::kAllExtensionNumbersOfType: {
      auto numbers = ExtensionNumbers(request.all_extension_numbers_of_type());
      if (numbers.ok()) *response.mutable_all_extension_numbers_response() = *std::move(numbers);
      status = numbers.status();
      break;
    }
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

absl::StatusOr<rv1::FileDescriptorResponse> ReflectionV1Service::FileByName(
    const std::string& name) const {
  const google::protobuf::FileDescriptor* file = pool_->FindFileByName(name);
  if (!file) return absl::NotFoundError(absl::StrFormat("file '%s' not found", Echo(name)));
  return FileAndImports(file);
}

absl::StatusOr<rv1::FileDescriptorResponse> ReflectionV1Service::FileContainingSymbol(
    const std::string& symbol) const {
  const google::protobuf::FileDescriptor* file = pool_->FindFileContainingSymbol(symbol);
  if (!file) return absl::NotFoundError(absl::StrFormat("symbol '%s' not found", Echo(symbol)));
  return FileAndImports(file);
}

absl::StatusOr<rv1::FileDescriptorResponse> ReflectionV1Service::FileContainingExtension(
    const rv1::ExtensionRequest& request) const {
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
  return FileAndImports(extension->file());
}

absl::StatusOr<rv1::ExtensionNumberResponse> ReflectionV1Service::ExtensionNumbers(
    const std::string& type_name) const {
  const auto* type = pool_->FindMessageTypeByName(type_name);
  if (!type) return absl::NotFoundError(absl::StrFormat("type '%s' not found", Echo(type_name)));
  std::vector<const google::protobuf::FieldDescriptor*> extensions;
  pool_->FindAllExtensions(type, &extensions);
  rv1::ExtensionNumberResponse out;
  out.set_base_type_name(type->full_name());
  for (const auto* extension : extensions) out.add_extension_number(extension->number());
  return out;
}

rv1::ListServiceResponse ReflectionV1Service::ListServices() const {
  rv1::ListServiceResponse out;
  if (services_) {
    for (const std::string& name : *services_) out.add_service()->set_name(name);
  }
  return out;
}

void AddReflectionV1(grpc::ServerBuilder& builder) {
  builder.SetOption(std::make_unique<ReflectionV1Option>());
}

}  // namespace geodesic::server
