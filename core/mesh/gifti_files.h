// GIFTI files (the XML format of FreeSurfer, HCP and Connectome Workbench):
// surfaces read as a TriangleSoup, and per-vertex values written as a metric.
//
// A surface (x.surf.gii) is one NIFTI_INTENT_POINTSET array (float32 or
// float64, N x 3) and one NIFTI_INTENT_TRIANGLE array (int32, M x 3; int64
// and uint32 are read too), row- or column-major, little- or big-endian, in
// ASCII, Base64Binary or GZipBase64Binary encoding; other arrays (shapes,
// labels) are checked and skipped.
// Our own reader, over expat and zlib, since no input may crash the process
// or make it allocate what the file cannot hold (libgiftiio did both): the
// whole file is parsed in one expat call, each element checked against the
// GIFTI schema as it opens, attribute values capped at 64 KiB; each surface
// array's declared size is checked, against the budget and against what its
// data could hold, before anything is decoded, and its data then decoded
// (zlib streamed) into exactly that size. External-file data is refused: a
// file naming another file on the server's disk must not make it read that
// file. No global state: reads may run on any number of threads at once.
#ifndef GEODESIC_CORE_MESH_GIFTI_FILES_H_
#define GEODESIC_CORE_MESH_GIFTI_FILES_H_

#include <cstdint>
#include <string>
#include <string_view>

#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "core/mesh/mesh.h"

namespace geodesic {

// The vertices and triangles of the GIFTI surface in `bytes`, in the file's
// order; `name` is used in messages. INVALID_ARGUMENT naming `name` and the
// problem for a file that is malformed, truncated or not GIFTI (an element
// where the schema has none, with its parent and line), a missing or
// misshapen pointset or triangle array, a data type other than those above,
// data that does not match its declared size, external-file data, or a
// negative index. RESOURCE_EXHAUSTED, before any of their data is decoded,
// when the two arrays declare more than `max_decoded_bytes` between them
// (0: no budget; a declaration beyond what the data could hold is refused
// all the same). Finite coordinates and indices below the vertex count are
// left to the mesh reader, which checks them for every format.
absl::StatusOr<TriangleSoup> ReadGiftiSurfaceFromMemory(std::string_view bytes,
                                                        std::string_view name,
                                                        uint64_t max_decoded_bytes = 0);

// The same for the file at `path`.
absl::StatusOr<TriangleSoup> ReadGiftiSurface(const std::string& path, std::string_view name,
                                              uint64_t max_decoded_bytes = 0);

// A GIFTI metric (x.func.gii) holding `values` as one NIFTI_INTENT_SHAPE
// float32 array, GZipBase64Binary, little-endian: the file's bytes
// (RESOURCE_EXHAUSTED if zlib cannot allocate).
// +inf stays +inf (IEEE float32 holds it; libgiftiio and nibabel read it
// back as inf).
absl::StatusOr<std::string> GiftiMetricBytes(absl::Span<const double> values);

}  // namespace geodesic

#endif  // GEODESIC_CORE_MESH_GIFTI_FILES_H_
