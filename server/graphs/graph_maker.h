// The seam through which the graph cache opens, builds and writes graph
// files (GraphMaker): the real steps call core/, and tests substitute their
// own maker to hold an entry in any state or make any step fail.
#ifndef GEODESIC_SERVER_GRAPH_MAKER_H_
#define GEODESIC_SERVER_GRAPH_MAKER_H_

#include <memory>
#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/dgg/dgg_build.h"
#include "core/dgg/graph_file.h"
#include "core/query/certified_graph.h"

namespace geodesic::server {
// How an entry gets its graph. The cache's own steps (load, build, persist)
// call these; tests substitute them to hold an entry in any state.
class GraphMaker {
 public:
  virtual ~GraphMaker() = default;
  // The graph in `path`, which must be for `mesh` and `params`; NOT_FOUND
  // when there is no file.
  virtual absl::StatusOr<std::shared_ptr<const DggGraph>> Open(const std::string& path,
                                                               const Mesh& mesh,
                                                               const DggParams& params,
                                                               GraphFile::Check check);
  // BuildDgg; with options.edge_file set, into the cache's draft of the
  // graph's file. RESOURCE_EXHAUSTED when the build runs out of memory, or
  // of disk for the edges kept in that file.
  virtual absl::StatusOr<std::shared_ptr<const DggGraph>> Build(const Mesh& mesh,
                                                                const DggBuildOptions& options);
  // A graph built in memory (a certified one): GraphFile::Write.
  virtual absl::Status Write(const DggGraph& graph, const std::string& path);
  // A graph built into `draft` (through its edge_file): commits the file,
  // GraphFileDraft::Finish.
  virtual absl::Status Finish(GraphFileDraft draft, const DggGraph& graph);

  // A certified graph: BuildCertifiedGraph.
  virtual absl::StatusOr<CertifiedGraph> BuildCertified(std::shared_ptr<const Mesh> mesh,
                                                        double max_error,
                                                        const CertifyOptions& options);
  // The certified graph in `path` and the certificate of its sidecar, which
  // must certify that file for `max_error`; the graph's build record must
  // be `params` but for its epsilon, the certificate's. NOT_FOUND when there
  // is no file; any other error rejects the file (it is rebuilt).
  struct Certified {
    std::shared_ptr<const DggGraph> graph;
    GraphCertificate certificate;
  };
  virtual absl::StatusOr<Certified> OpenCertified(const std::string& path, const Mesh& mesh,
                                                  const DggParams& params, double max_error,
                                                  GraphFile::Check check);
  // Writes the certificate sidecar of `graph`, already written to `path`.
  virtual absl::Status WriteCertificate(const DggGraph& graph, const std::string& path,
                                        const GraphCertificate& certificate);
};

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_GRAPH_MAKER_H_
