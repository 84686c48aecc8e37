// A certified graph's certificate (core/query/certified_graph.h) beside its
// graph file, as a small JSON sidecar "<graph>.certificate.json".
//
// The sidecar names the graph it measured (mesh fingerprint, epsilon, file
// size), so that one left beside a graph rebuilt under the same name is
// refused rather than believed.
#ifndef GEODESIC_SERVER_OFFLINE_CERTIFICATE_FILE_H_
#define GEODESIC_SERVER_OFFLINE_CERTIFICATE_FILE_H_

#include <optional>
#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/dgg/graph_file.h"
#include "core/query/certified_graph.h"
#include "nlohmann/json.hpp"

namespace geodesic::offline {

std::string CertificatePath(const std::string& graph_path);

// The certificate's keys, in the order --json prints them: max_error_bound,
// epsilon, measured_max_error, measured_mean_error, sources, seed, sound,
// builds.
nlohmann::ordered_json CertificateJson(const GraphCertificate& certificate);

// Writes the sidecar of `graph`, already written to `graph_path`,
// atomically.
absl::Status WriteCertificate(const std::string& graph_path, const DggGraph& graph,
                              const GraphCertificate& certificate);

// Removes the sidecar of `graph_path`, if any: a graph written without a
// certificate must not inherit its predecessor's.
absl::Status RemoveCertificate(const std::string& graph_path);

// The sidecar of the graph file described by `graph`, or nullopt when there
// is none. DATA_LOSS when it is not a certificate; FAILED_PRECONDITION when
// it certifies another graph (naming what differs).
absl::StatusOr<std::optional<GraphCertificate>> ReadCertificate(const std::string& graph_path,
                                                                const GraphFile::Info& graph);

}  // namespace geodesic::offline

#endif  // GEODESIC_SERVER_OFFLINE_CERTIFICATE_FILE_H_
