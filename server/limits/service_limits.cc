#include "server/limits/service_limits.h"

#include <algorithm>

namespace geodesic::server {
namespace {

// The most a request's parts take on the wire when they are valid (a face
// point is 35 bytes, a pair of them 76), with room to spare for fields a
// newer client adds; and what a request may hold besides them (names).
constexpr uint64_t kPointWireBytes = 64;
constexpr uint64_t kPairWireBytes = 128;
constexpr uint64_t kRequestWireOverhead = 64 << 10;

// Room for a list that grows with a mesh: 4M ids of up to four bytes (a
// region of half an 8M-face mesh, a field's targets), and for an upload's
// messages.
constexpr uint64_t kMeshListRequestBytes = uint64_t{16} << 20;

}  // namespace

uint64_t DistanceRequestBytes(const ServiceLimits& limits) {
  return limits.max_pairs * kPairWireBytes + kRequestWireOverhead;
}
uint64_t MatrixRequestBytes(const ServiceLimits& limits) {
  return (uint64_t(limits.max_sources) + limits.max_pairs) * kPointWireBytes + kRequestWireOverhead;
}
uint64_t SnapRequestBytes(const ServiceLimits& limits) {
  return limits.max_pairs * kPointWireBytes + kRequestWireOverhead;
}

uint64_t MaxRequestBytes(const ServiceLimits& limits) {
  return std::max({DistanceRequestBytes(limits), MatrixRequestBytes(limits),
                   SnapRequestBytes(limits), kMeshListRequestBytes});
}

}  // namespace geodesic::server
