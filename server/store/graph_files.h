// The names of the daemon's graph files in --graph-dir.
#ifndef GEODESIC_SERVER_STORE_GRAPH_FILES_H_
#define GEODESIC_SERVER_STORE_GRAPH_FILES_H_

#include <cstdint>
#include <string>

#include "core/dgg/dgg_build.h"

namespace geodesic::server {

// The graph's file name in --graph-dir: GraphFileName for a plain graph;
// for a certified one the bound takes the epsilon's place
// ("<fingerprint>-cert0.01-r3.dgg"), since the epsilon is chosen by the
// build. Its certificate is the sidecar beside it
// (server/offline/certificate_file.h).
std::string CachedGraphFileName(uint64_t mesh_fingerprint, const DggParams& params,
                                double max_error);

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_STORE_GRAPH_FILES_H_
