// The whole build of a discrete geodesic graph, as everything that builds
// one calls it: the build's phases (core/dgg/dgg_build.h), then every fan
// narrowed by the solver's own sweeps (NarrowAllFans), which leaves each
// search relaxing a fraction of the turns that paths of two edges allow.
// The narrowing lives here, a stage above the build, because its sweeps
// are the query stage's (core/query/field_lanes.h).
#ifndef GEODESIC_CORE_QUERY_BUILD_DGG_H_
#define GEODESIC_CORE_QUERY_BUILD_DGG_H_

#include <memory>
#include <vector>

#include "absl/status/statusor.h"
#include "core/dgg/dgg_build.h"
#include "core/dgg/dgg_graph.h"
#include "core/mesh/mesh.h"

namespace geodesic {

// Fails with INVALID_ARGUMENT for epsilon outside (0, 1) or NaN, and with
// CANCELLED when the progress callback asks to stop.
absl::StatusOr<std::shared_ptr<const DggGraph>> BuildDgg(const Mesh& mesh,
                                                         const DggBuildOptions& options,
                                                         DggBuildStats* stats = nullptr);

// A distributed build's parts joined (MergeDggPartsWithTwoEdgeFans), then
// its fans narrowed as BuildDgg's: the same graph, bit for bit.
absl::StatusOr<std::shared_ptr<const DggGraph>> MergeDggParts(const Mesh& mesh,
                                                              std::vector<DggPartSource> parts,
                                                              const DggBuildOptions& options,
                                                              DggBuildStats* stats = nullptr);
absl::StatusOr<std::shared_ptr<const DggGraph>> MergeDggParts(const Mesh& mesh,
                                                              std::vector<DggCandidatePart> parts,
                                                              const DggBuildOptions& options,
                                                              DggBuildStats* stats = nullptr);

}  // namespace geodesic

#endif  // GEODESIC_CORE_QUERY_BUILD_DGG_H_
