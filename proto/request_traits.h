// How gRPC reads protobuf messages in this project. Its own traits answer a
// message that does not parse with INTERNAL, which tells a client that sent
// a malformed request that the server failed. These answer INVALID_ARGUMENT
// naming the message instead. The generated service code reads unary
// requests through the traits of MessageLite (their base class) and
// streaming calls' requests through their own type's, so both are replaced.
// The build includes this header first in every file that uses the stubs
// (proto/CMakeLists.txt), the generated ones included, so that all of them
// read messages the same way. A reply that does not parse reads the same
// way at a client, which names the message too.
#ifndef GEODESIC_PROTO_REQUEST_TRAITS_H_
#define GEODESIC_PROTO_REQUEST_TRAITS_H_

#include <grpcpp/impl/codegen/proto_utils.h>

#include <string>

namespace geodesic::v1 {
class RegisterMeshRequest;
class RegisterRegionRequest;
class UploadMeshRequest;
class ListMeshesRequest;
class GetMeshRequest;
class UnloadMeshRequest;
class RequestGraphRequest;
class GetGraphRequest;
class ListGraphsRequest;
class CancelGraphRequest;
class DistanceFieldRequest;
class DistanceRequest;
class MatrixRequest;
class SnapRequest;
class SamplePointsRequest;
}  // namespace geodesic::v1

namespace grpc {

template <>
class SerializationTraits<protobuf::MessageLite, void> {
 public:
  static Status Serialize(const protobuf::MessageLite& message, ByteBuffer* buffer,
                          bool* own_buffer) {
    return GenericSerialize<ProtoBufferWriter, protobuf::MessageLite>(message, buffer, own_buffer);
  }
  static Status Deserialize(ByteBuffer* buffer, protobuf::MessageLite* message) {
    Status read = GenericDeserialize<ProtoBufferReader, protobuf::MessageLite>(buffer, message);
    if (read.error_code() != StatusCode::INTERNAL) return read;
    return Status(StatusCode::INVALID_ARGUMENT,
                  "malformed " + message->GetTypeName() + ": the bytes are not that message");
  }
};

#define GEODESIC_READ_AS_MESSAGE_LITE(Message)           \
  template <>                                            \
  class SerializationTraits<geodesic::v1::Message, void> \
      : public SerializationTraits<protobuf::MessageLite, void> {};

GEODESIC_READ_AS_MESSAGE_LITE(RegisterMeshRequest)
GEODESIC_READ_AS_MESSAGE_LITE(RegisterRegionRequest)
GEODESIC_READ_AS_MESSAGE_LITE(UploadMeshRequest)
GEODESIC_READ_AS_MESSAGE_LITE(ListMeshesRequest)
GEODESIC_READ_AS_MESSAGE_LITE(GetMeshRequest)
GEODESIC_READ_AS_MESSAGE_LITE(UnloadMeshRequest)
GEODESIC_READ_AS_MESSAGE_LITE(RequestGraphRequest)
GEODESIC_READ_AS_MESSAGE_LITE(GetGraphRequest)
GEODESIC_READ_AS_MESSAGE_LITE(ListGraphsRequest)
GEODESIC_READ_AS_MESSAGE_LITE(CancelGraphRequest)
GEODESIC_READ_AS_MESSAGE_LITE(DistanceFieldRequest)
GEODESIC_READ_AS_MESSAGE_LITE(DistanceRequest)
GEODESIC_READ_AS_MESSAGE_LITE(MatrixRequest)
GEODESIC_READ_AS_MESSAGE_LITE(SnapRequest)
GEODESIC_READ_AS_MESSAGE_LITE(SamplePointsRequest)

#undef GEODESIC_READ_AS_MESSAGE_LITE

}  // namespace grpc

#endif  // GEODESIC_PROTO_REQUEST_TRAITS_H_
