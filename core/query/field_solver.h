// The DGG-tailored single-source solver (section 5.1.2 of the paper): a
// label-correcting search in which each node relaxes only the fan of the edge
// it was reached by. Internal to core/query/: GeodesicEngine::Field and
// Matrix are its public face.
#ifndef GEODESIC_CORE_QUERY_FIELD_SOLVER_H_
#define GEODESIC_CORE_QUERY_FIELD_SOLVER_H_

#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "core/dgg/dgg_graph.h"
#include "core/mesh/mesh.h"
#include "core/query/augmented_graph.h"
#include "core/query/geodesic_engine.h"
#include "core/query/graph_search.h"
#include "core/query/query_scratch.h"

namespace geodesic::query_internal {

// The field from sources already joined to the graph.
// `fan_layout`: LaneFanLayoutFor(g), or kWhole.
absl::StatusOr<FieldResult> SolveField(const Mesh& mesh, const DggGraph& g,
                                       const BucketShape& bucket_shape, LaneFanLayout fan_layout,
                                       QueryScratch& sc, absl::Span<const Endpoint> sources,
                                       const FieldOptions& options);

}  // namespace geodesic::query_internal

#endif  // GEODESIC_CORE_QUERY_FIELD_SOLVER_H_
