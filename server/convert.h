// Conversions between the API's messages and core types.
#ifndef GEODESIC_SERVER_CONVERT_H_
#define GEODESIC_SERVER_CONVERT_H_

#include <cstddef>
#include <string>
#include <string_view>

#include "absl/status/statusor.h"
#include "core/surface_point.h"
#include "geodesic/v1/geodesic.pb.h"
#include "grpcpp/support/status.h"
#include "server/graph_cache.h"

namespace geodesic::server {

absl::StatusOr<SurfacePoint> FromProto(const v1::SurfacePoint& p, const Mesh& mesh,
                                       const std::string& what);
v1::SurfacePoint ToProto(const SurfacePoint& p);
void ToProto(const GraphStatus& s, v1::Graph* out);
grpc::Status ToGrpc(const absl::Status& s);

// How much of a client's own input an error message repeats back.
inline constexpr size_t kMaxEcho = 80;
// At most kMaxEcho characters of `input` for an error message, with
// control and non-ASCII bytes escaped and, when cut, the full length named:
// an answer (and its log line) must not grow with what a client sends.
std::string Echo(std::string_view input);

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_CONVERT_H_
