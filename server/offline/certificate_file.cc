#include "server/offline/certificate_file.h"

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "absl/strings/numbers.h"
#include "absl/strings/str_format.h"
#include "core/base/atomic_file.h"
#include "core/base/status.h"

namespace geodesic::offline {
namespace {

using Json = nlohmann::ordered_json;

constexpr char kFormat[] = "geodesicd graph certificate";
constexpr int kVersion = 1;

std::string Hex(uint64_t v) { return absl::StrFormat("%016x", static_cast<unsigned long long>(v)); }

// Which graph a certificate measured.
Json GraphJson(uint64_t mesh_fingerprint, double epsilon, uint64_t file_bytes) {
  return {{"mesh_fingerprint", Hex(mesh_fingerprint)},
          {"epsilon", epsilon},
          {"file_bytes", file_bytes}};
}

absl::StatusOr<GraphCertificate> ParseCertificate(const Json& c) {
  GraphCertificate out;
  try {
    out.max_error_bound = c.at("max_error_bound").get<double>();
    out.epsilon = c.at("epsilon").get<double>();
    out.measured_max_error = c.at("measured_max_error").get<double>();
    out.measured_mean_error = c.at("measured_mean_error").get<double>();
    out.sources = c.at("sources").get<uint32_t>();
    out.seed = c.at("seed").get<uint64_t>();
    out.sound = c.at("sound").get<bool>();
    out.builds = c.at("builds").get<uint32_t>();
  } catch (const Json::exception& e) {
    return absl::DataLossError(e.what());
  }
  return out;
}

}  // namespace

std::string CertificatePath(const std::string& graph_path) {
  return graph_path + ".certificate.json";
}

Json CertificateJson(const GraphCertificate& c) {
  return {{"max_error_bound", c.max_error_bound},
          {"epsilon", c.epsilon},
          {"measured_max_error", c.measured_max_error},
          {"measured_mean_error", c.measured_mean_error},
          {"sources", c.sources},
          {"seed", c.seed},
          {"sound", c.sound},
          {"builds", c.builds}};
}

absl::Status WriteCertificate(const std::string& graph_path, const DggGraph& graph,
                              const GraphCertificate& certificate) {
  std::error_code ec;
  const uint64_t bytes = std::filesystem::file_size(graph_path, ec);
  if (ec) return absl::NotFoundError(absl::StrFormat("%s: %s", graph_path, ec.message()));
  const Json sidecar = {
      {"format", kFormat},
      {"version", kVersion},
      {"graph", GraphJson(graph.mesh_fingerprint(), graph.params().epsilon, bytes)},
      {"certificate", CertificateJson(certificate)}};
  const std::string text = sidecar.dump(2) + "\n";
  const std::string path = CertificatePath(graph_path);
  ASSIGN_OR_RETURN(AtomicFileWriter writer, AtomicFileWriter::Create(path));
  RETURN_IF_ERROR(writer.Append(text.data(), text.size()));
  return std::move(writer).Commit();
}

absl::Status RemoveCertificate(const std::string& graph_path) {
  const std::string path = CertificatePath(graph_path);
  if (std::remove(path.c_str()) != 0 && errno != ENOENT) return ErrnoStatus("remove", path);
  return absl::OkStatus();
}

absl::StatusOr<std::optional<GraphCertificate>> ReadCertificate(const std::string& graph_path,
                                                                const GraphFile::Info& graph) {
  const std::string path = CertificatePath(graph_path);
  std::ifstream in(path);
  if (!in) {
    if (errno == ENOENT) return std::nullopt;
    return ErrnoStatus("open", path);
  }
  std::stringstream text;
  text << in.rdbuf();
  const Json sidecar = Json::parse(text.str(), nullptr, /*allow_exceptions=*/false);
  if (sidecar.is_discarded() || !sidecar.is_object() || sidecar.value("format", "") != kFormat ||
      sidecar.value("version", 0) != kVersion || !sidecar.contains("certificate")) {
    return absl::DataLossError(absl::StrFormat(
        "%s: not a graph certificate (format '%s', version %d)", path, kFormat, kVersion));
  }
  const Json want = GraphJson(graph.mesh_fingerprint, graph.params.epsilon, graph.file_bytes);
  if (sidecar.value("graph", Json()) != want) {
    return absl::FailedPreconditionError(
        absl::StrFormat("%s certifies another graph (%s), not %s (%s)", path,
                        sidecar.value("graph", Json()).dump(), graph_path, want.dump()));
  }
  auto certificate = ParseCertificate(sidecar["certificate"]);
  if (!certificate.ok()) {
    return absl::DataLossError(absl::StrFormat("%s: %s", path, certificate.status().message()));
  }
  return *certificate;
}

}  // namespace geodesic::offline
