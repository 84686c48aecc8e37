// Exact landmarks kept between runs of a process: computing them takes one
// exact field per landmark (seconds to minutes), reading them back a
// fraction of a second. The file holds the fields for one mesh and landmark
// count; the face frames are made again from the mesh.
#ifndef GEODESIC_CORE_QUERY_EXACT_LANDMARKS_FILE_H_
#define GEODESIC_CORE_QUERY_EXACT_LANDMARKS_FILE_H_

#include <cstdint>
#include <memory>
#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/mesh/mesh.h"
#include "core/query/exact_landmarks.h"

namespace geodesic {

// Where a graph file's exact landmarks are kept beside it.
inline std::string ExactLandmarksPathOf(const std::string& graph_path) {
  return graph_path + ".exact-landmarks";
}

// The bytes of the file WriteExactLandmarks makes of `landmarks`.
uint64_t ExactLandmarksFileBytes(const ExactLandmarks& landmarks);

// Writes atomically (temp + fsync + rename) landmarks computed on `mesh`.
absl::Status WriteExactLandmarks(const ExactLandmarks& landmarks, const Mesh& mesh,
                                 const std::string& path);

// Reads landmarks written for `mesh` with `count` landmarks. NOT_FOUND when
// there is no file; FAILED_PRECONDITION, naming the path and the field, when
// it was written for another mesh or count, or by another format version;
// DATA_LOSS when it is foreign, truncated or corrupt.
absl::StatusOr<std::unique_ptr<const ExactLandmarks>> ReadExactLandmarks(const std::string& path,
                                                                         const Mesh& mesh,
                                                                         int count);

}  // namespace geodesic

#endif  // GEODESIC_CORE_QUERY_EXACT_LANDMARKS_FILE_H_
