#include "server/meshes/upload.h"

#include <openssl/evp.h>

#include <algorithm>
#include <bit>
#include <initializer_list>
#include <memory>

#include "absl/strings/ascii.h"
#include "absl/strings/escaping.h"
#include "absl/strings/str_format.h"
#include "core/base/status.h"
#include "core/mesh/mesh_io.h"
#include "server/base/echo.h"
#include "server/meshes/mesh_registry.h"

namespace geodesic::server {
namespace {

// The slowest an upload may come, on average, once it has had
// kUploadGrace to get going: a client holding an upload open with a trickle
// of bytes holds a stream slot and its share of the limit for nothing.
constexpr uint64_t kMinUploadBytesPerSecond = 16 << 10;
constexpr absl::Duration kUploadGrace = absl::Seconds(30);

static_assert(std::endian::native == std::endian::little,
              "array payloads are hashed as they lie in memory: little-endian");

// SHA-256 of the concatenation of `parts`, lower-case hex.
std::string HexSha256(std::initializer_list<std::string_view> parts) {
  std::unique_ptr<EVP_MD_CTX, decltype(&EVP_MD_CTX_free)> ctx(EVP_MD_CTX_new(), EVP_MD_CTX_free);
  unsigned char digest[EVP_MAX_MD_SIZE];
  unsigned int length = 0;
  bool ok = ctx && EVP_DigestInit_ex(ctx.get(), EVP_sha256(), nullptr) == 1;
  for (std::string_view part : parts) {
    ok = ok && EVP_DigestUpdate(ctx.get(), part.data(), part.size()) == 1;
  }
  ok = ok && EVP_DigestFinal_ex(ctx.get(), digest, &length) == 1;
  // No SHA-256 (an OpenSSL without it) matches no declared hash: the
  // upload is refused, never accepted unchecked.
  if (!ok) return "unavailable";
  return absl::BytesToHexString(absl::string_view(reinterpret_cast<const char*>(digest), length));
}

bool IsSha256Hex(std::string_view s) {
  if (s.size() != 64) return false;
  for (char c : s) {
    if (!absl::ascii_isxdigit(static_cast<unsigned char>(c))) return false;
  }
  return true;
}

}  // namespace

absl::Status CheckUploadRate(const UploadAssembler& upload, absl::Duration elapsed) {
  if (elapsed < kUploadGrace || upload.received_bytes() >= upload.declared_bytes()) {
    return absl::OkStatus();
  }
  const double rate = upload.received_bytes() / absl::ToDoubleSeconds(elapsed);
  if (rate >= kMinUploadBytesPerSecond) return absl::OkStatus();
  return absl::DeadlineExceededError(absl::StrFormat(
      "the upload of '%s' came at %.0f bytes/s over %.0f s (%u of %u bytes), below the minimum "
      "of %u bytes/s; nothing was registered",
      upload.name(), rate, absl::ToDoubleSeconds(elapsed), upload.received_bytes(),
      upload.declared_bytes(), kMinUploadBytesPerSecond));
}

std::string Sha256Hex(std::string_view bytes) { return HexSha256({bytes}); }

std::string Sha256HexOfArrays(const std::vector<double>& vertices,
                              const std::vector<uint32_t>& faces) {
  return HexSha256({std::string_view(reinterpret_cast<const char*>(vertices.data()),
                                     vertices.size() * sizeof(double)),
                    std::string_view(reinterpret_cast<const char*>(faces.data()),
                                     faces.size() * sizeof(uint32_t))});
}

void SplitUpload(v1::UploadMeshRequest header, std::string_view data,
                 const std::vector<double>& vertices, const std::vector<uint32_t>& faces,
                 const std::function<bool(const v1::UploadMeshRequest&)>& send) {
  v1::UploadMeshRequest message = std::move(header);
  size_t sent_data = 0, sent_vertices = 0, sent_faces = 0;
  do {
    uint64_t room = kUploadMessageBytes;
    const size_t bytes = std::min<size_t>(room, data.size() - sent_data);
    message.set_data(std::string(data.substr(sent_data, bytes)));
    sent_data += bytes;
    room -= bytes;
    const size_t coordinates =
        std::min<size_t>(room / sizeof(double), vertices.size() - sent_vertices);
    message.mutable_vertices()->Add(vertices.begin() + sent_vertices,
                                    vertices.begin() + sent_vertices + coordinates);
    sent_vertices += coordinates;
    room -= coordinates * sizeof(double);
    const size_t ids = std::min<size_t>(room / sizeof(uint32_t), faces.size() - sent_faces);
    message.mutable_faces()->Add(faces.begin() + sent_faces, faces.begin() + sent_faces + ids);
    sent_faces += ids;
    if (!send(message)) return;
    message.Clear();
  } while (sent_data < data.size() || sent_vertices < vertices.size() || sent_faces < faces.size());
}

absl::Status UploadAssembler::First(const v1::UploadMeshRequest& message) {
  RETURN_IF_ERROR(MeshRegistry::ValidateName(message.name()));
  name_ = message.name();
  // Without a declared size and hash an upload cut short cannot be told
  // from a whole one (clients from before they were required send neither).
  if (message.total_bytes() == 0) {
    return absl::InvalidArgumentError(
        "the first message of an upload must declare total_bytes, the payload's size in bytes");
  }
  if (message.sha256().empty()) {
    return absl::InvalidArgumentError(
        "the first message of an upload must declare sha256, the payload's SHA-256 in hex");
  }
  if (!IsSha256Hex(message.sha256())) {
    return absl::InvalidArgumentError(
        absl::StrFormat("sha256 must be 64 hex digits, not '%s'", Echo(message.sha256())));
  }
  if (message.total_bytes() > max_bytes_) {
    return absl::ResourceExhaustedError(
        absl::StrFormat("an upload of %u bytes exceeds the limit of %u bytes (--max-upload-bytes)",
                        message.total_bytes(), max_bytes_));
  }
  format_ = absl::AsciiStrToLower(message.format());
  if (!format_.empty() && !IsMeshFormat(format_)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("unknown mesh format '%s' (supported: %s; empty for arrays)",
                        Echo(message.format()), MeshFormatList()));
  }
  total_bytes_ = message.total_bytes();
  sha256_ = absl::AsciiStrToLower(message.sha256());
  repair_ = message.repair_non_manifold();
  return absl::OkStatus();
}

absl::Status UploadAssembler::Add(v1::UploadMeshRequest& message) {
  if (!started_) {
    RETURN_IF_ERROR(First(message));
    started_ = true;
  } else if (!message.name().empty() || !message.format().empty() || message.total_bytes() != 0 ||
             !message.sha256().empty() || message.repair_non_manifold()) {
    return absl::InvalidArgumentError(
        "only the first message of an upload carries name, format, total_bytes, sha256 and "
        "repair_non_manifold");
  }
  has_bytes_ |= !message.data().empty();
  arrays_ |= message.vertices_size() > 0 || message.faces_size() > 0;
  if (has_bytes_ && arrays_) {
    return absl::InvalidArgumentError(
        "an upload carries a file's bytes (data) or arrays (vertices and faces), not both");
  }
  if (has_bytes_ && format_.empty()) {
    return absl::InvalidArgumentError(
        absl::StrFormat("an upload of a file's bytes names its format (%s)", MeshFormatList()));
  }
  if (arrays_ && !format_.empty()) {
    return absl::InvalidArgumentError(
        "an upload of arrays leaves format empty: it names a file format");
  }
  const uint64_t size = message.data().size() + sizeof(double) * message.vertices_size() +
                        sizeof(uint32_t) * message.faces_size();
  if (size > total_bytes_ - received_) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "the upload sent more than the %u bytes it declared (total_bytes)", total_bytes_));
  }
  received_ += size;
  if (bytes_.empty()) {
    bytes_.swap(*message.mutable_data());
  } else {
    bytes_ += message.data();
  }
  vertices_.insert(vertices_.end(), message.vertices().begin(), message.vertices().end());
  faces_.insert(faces_.end(), message.faces().begin(), message.faces().end());
  return absl::OkStatus();
}

absl::Status UploadAssembler::Finish() {
  if (!started_) return absl::InvalidArgumentError("an upload needs at least one message");
  if (received_ != total_bytes_) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "the upload ended after %u of the %u bytes it declared (total_bytes): it was cut short, "
        "or a message could not be parsed; nothing was registered",
        received_, total_bytes_));
  }
  const std::string actual = arrays_ ? Sha256HexOfArrays(vertices_, faces_) : Sha256Hex(bytes_);
  if (actual != sha256_) {
    return absl::InvalidArgumentError(
        absl::StrFormat("the upload's SHA-256 is %s, not the %s declared; nothing was registered",
                        actual, sha256_));
  }
  return absl::OkStatus();
}

}  // namespace geodesic::server
