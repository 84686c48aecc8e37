// Files that hold query results, in the format a path's extension names, for
// the offline commands and the CLI alike:
//
//  - distance fields, one value per vertex in the mesh file's order: .f64
//    (raw little-endian float64, +inf where unreached), .npy (NumPy '<f8'),
//    .csv (vertex,distance), .ply (the mesh coloured by distance, blue near
//    to red far with isolines, grey unreached, the value as a property),
//    .func.gii (a GIFTI metric: float32, +inf where unreached);
//  - labels (the nearest source of each vertex): .npy ('<u4'), .csv, .u32
//    (raw little-endian uint32), 4294967295 where unreached;
//  - paths as polylines: .csv (x,y,z), .ply (vertices and edges), .obj
//    (v lines and one l line).
//  - distance matrices (core/query/matrix_files.h): dense .npy, sparse
//    .npz (scipy.sparse's CSR layout).
//
// An extension not listed is refused with INVALID_ARGUMENT naming it and
// the ones accepted, before anything is written. Files are written
// atomically (core/base/atomic_file.h).
#ifndef GEODESIC_CORE_QUERY_RESULT_FILES_H_
#define GEODESIC_CORE_QUERY_RESULT_FILES_H_

#include <cstdint>
#include <initializer_list>
#include <string>
#include <string_view>

#include "absl/status/status.h"
#include "absl/types/span.h"
#include "core/base/vec.h"
#include "core/mesh/mesh.h"

namespace geodesic {

// OK if `path` names a format WriteField can write (and, for .ply, that
// needs the mesh's geometry: `have_geometry`).
absl::Status CheckFieldPath(const std::string& path, bool have_geometry);
absl::Status CheckLabelPath(const std::string& path);
absl::Status CheckPolylinePath(const std::string& path);
absl::Status CheckMatrixPath(const std::string& path, bool sparse);

// The start of a NumPy format 1.0 file (magic, version, header length and the
// header dict, padded so that the data starts 64 bytes in or at a multiple
// of 64) for a little-endian C-order array of `dtype` ('<f8', '|S3') and
// `shape` ({} for a 0-d array).
std::string NpyPreamble(std::string_view dtype, std::initializer_list<uint64_t> shape);

// `geometry` is needed for .ply only, with one position per value.
absl::Status WriteField(const std::string& path, absl::Span<const double> values,
                        const TriangleSoup* geometry = nullptr);
absl::Status WriteLabels(const std::string& path, absl::Span<const uint32_t> labels);
absl::Status WritePolyline(const std::string& path, absl::Span<const Vec3> points);

}  // namespace geodesic

#endif  // GEODESIC_CORE_QUERY_RESULT_FILES_H_
