// An UploadMesh stream put together message by message, and checked against
// what its first message declared: the gRPC handler only feeds it, so the
// rules of an upload are testable without a server.
#ifndef GEODESIC_SERVER_UPLOAD_H_
#define GEODESIC_SERVER_UPLOAD_H_

#include <cstdint>
#include <functional>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/time/time.h"
#include "geodesic/v1/geodesic.pb.h"

namespace geodesic::server {

// The payload one message of an upload carries, as the bundled clients and
// the HTTP gateway send it: far below the largest request the server takes
// (MaxRequestBytes, limits/service_limits.h), and small beside gRPC's receive
// buffers, which uploads side by side share.
inline constexpr uint64_t kUploadMessageBytes = uint64_t{1} << 20;

// `header` (name, format, total_bytes, sha256, repair_non_manifold) with
// the payload, a file's `data` or the arrays, split into messages of at
// most kUploadMessageBytes of payload each; `send` takes them in order and
// returns false to stop (the stream broke).
void SplitUpload(v1::UploadMeshRequest header, std::string_view data,
                 const std::vector<double>& vertices, const std::vector<uint32_t>& faces,
                 const std::function<bool(const v1::UploadMeshRequest&)>& send);

class UploadAssembler {
 public:
  explicit UploadAssembler(uint64_t max_bytes) : max_bytes_(max_bytes) {}

  // Takes the next message (its payload is moved out). Refuses at once a
  // first message that does not declare total_bytes and sha256, a
  // declared size over the limit (RESOURCE_EXHAUSTED), a later message
  // repeating the first's fields, bytes mixed with arrays, and any payload
  // past the declared size.
  absl::Status Add(v1::UploadMeshRequest& message);
  // After the client half-closed: OK only if exactly the declared bytes
  // came and their SHA-256 is the declared one.
  absl::Status Finish();

  // Valid once the first message was taken.
  const std::string& name() const { return name_; }
  const std::string& format() const { return format_; }
  bool repair() const { return repair_; }
  // The payload's size, as the first message declared it, and how much of
  // it came so far.
  uint64_t declared_bytes() const { return total_bytes_; }
  uint64_t received_bytes() const { return received_; }
  // The payload, valid after Finish: a file's bytes, or arrays.
  bool arrays() const { return arrays_; }
  std::string& bytes() { return bytes_; }
  std::vector<double>& vertices() { return vertices_; }
  std::vector<uint32_t>& faces() { return faces_; }

 private:
  absl::Status First(const v1::UploadMeshRequest& message);

  const uint64_t max_bytes_;
  bool started_ = false;
  std::string name_, format_, sha256_;
  bool repair_ = false;
  uint64_t total_bytes_ = 0;
  uint64_t received_ = 0;
  bool has_bytes_ = false, arrays_ = false;
  std::string bytes_;
  std::vector<double> vertices_;
  std::vector<uint32_t> faces_;
};

// DEADLINE_EXCEEDED, naming the rate, when `upload` has come more slowly
// than a minimum rate on average over `elapsed`, once past a grace period
// for getting going: a client holding an upload open with a trickle of
// bytes would hold a stream slot and its share of the memory for nothing.
absl::Status CheckUploadRate(const UploadAssembler& upload, absl::Duration elapsed);

// Lower-case hex SHA-256 of `bytes`.
std::string Sha256Hex(std::string_view bytes);
// The same of the arrays' canonical bytes (UploadMeshRequest): each vertex
// coordinate as a little-endian float64, then each face index as a
// little-endian uint32.
std::string Sha256HexOfArrays(const std::vector<double>& vertices,
                              const std::vector<uint32_t>& faces);

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_UPLOAD_H_
