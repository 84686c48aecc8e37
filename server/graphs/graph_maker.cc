// The real GraphMaker: graph files opened, built, written and certified
// through core/, with nothing of the cache's bookkeeping, so that a test's
// maker can stand in for any one of these steps.
#include "server/graphs/graph_maker.h"

#include <filesystem>
#include <system_error>
#include <utility>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "core/dgg/dgg_graph.h"
#include "core/query/build_dgg.h"
#include "server/offline/certificate_file.h"

namespace geodesic::server {

absl::StatusOr<std::shared_ptr<const DggGraph>> GraphMaker::Open(const std::string& path,
                                                                 const Mesh& mesh,
                                                                 const DggParams& params,
                                                                 GraphFile::Check check) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) {
    return absl::NotFoundError(absl::StrFormat("no graph file %s", path));
  }
  return GraphFile::Open(path, mesh, check, &params);
}

absl::StatusOr<std::shared_ptr<const DggGraph>> GraphMaker::Build(const Mesh& mesh,
                                                                  const DggBuildOptions& options) {
  return BuildDgg(mesh, options);
}

absl::Status GraphMaker::Write(const DggGraph& graph, const std::string& path) {
  return GraphFile::Write(graph, path);
}

absl::Status GraphMaker::Finish(GraphFileDraft draft, const DggGraph& graph) {
  return std::move(draft).Finish(graph);
}

absl::StatusOr<CertifiedGraph> GraphMaker::BuildCertified(std::shared_ptr<const Mesh> mesh,
                                                          double max_error,
                                                          const CertifyOptions& options) {
  return BuildCertifiedGraph(std::move(mesh), max_error, options);
}

absl::StatusOr<GraphMaker::Certified> GraphMaker::OpenCertified(const std::string& path,
                                                                const Mesh& mesh,
                                                                const DggParams& params,
                                                                double max_error,
                                                                GraphFile::Check check) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) {
    return absl::NotFoundError(absl::StrFormat("no graph file %s", path));
  }
  // The epsilon is the build's choice: the certificate says which, and the
  // file must agree with it; every other field is the key's.
  auto graph = GraphFile::Open(path, mesh, check);
  if (!graph.ok()) return graph.status();
  GraphFile::Info info;
  info.mesh_fingerprint = (*graph)->mesh_fingerprint();
  info.params = (*graph)->params();
  info.file_bytes = std::filesystem::file_size(path, ec);
  if (ec) return absl::NotFoundError(absl::StrFormat("%s: %s", path, ec.message()));
  auto certificate = offline::ReadCertificate(path, info);
  if (!certificate.ok()) return certificate.status();
  if (!certificate->has_value()) {
    return absl::FailedPreconditionError(absl::StrFormat("%s has no certificate beside it (%s)",
                                                         path, offline::CertificatePath(path)));
  }
  const GraphCertificate& c = **certificate;
  if (c.max_error_bound != max_error || !c.sound || c.measured_max_error > max_error) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "%s certifies bound %g (measured max %g, %s), not %g", offline::CertificatePath(path),
        c.max_error_bound, c.measured_max_error, c.sound ? "sound" : "unsound", max_error));
  }
  DggParams want = params;
  want.epsilon = c.epsilon;
  if (absl::Status same = CheckSameParams(want, info.params, path); !same.ok()) return same;
  return Certified{*std::move(graph), c};
}

absl::Status GraphMaker::WriteCertificate(const DggGraph& graph, const std::string& path,
                                          const GraphCertificate& certificate) {
  return offline::WriteCertificate(path, graph, certificate);
}

}  // namespace geodesic::server
