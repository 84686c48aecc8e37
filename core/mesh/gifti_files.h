// GIFTI files (the XML format of FreeSurfer, HCP and Connectome Workbench):
// surfaces read as a TriangleSoup, and per-vertex values written as a metric.
//
// A surface (x.surf.gii) is one NIFTI_INTENT_POINTSET array (float32 or
// float64, N x 3) and one NIFTI_INTENT_TRIANGLE array (int32, M x 3; int64
// and uint32 are read too), row- or column-major, in ASCII, Base64Binary or
// GZipBase64Binary encoding.
// Reading goes through Debian's libgiftiio, after an expat pass that refuses
// what libgiftiio would read wrongly or only complain about on stderr:
// external-file data (a file naming another file on the server's disk must
// not make it read that file), data short of or beyond the declared size,
// bad base64 or zlib, and malformed attributes.
#ifndef GEODESIC_CORE_MESH_GIFTI_FILES_H_
#define GEODESIC_CORE_MESH_GIFTI_FILES_H_

#include <string>
#include <string_view>

#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "core/mesh/mesh.h"

namespace geodesic {

// The vertices and triangles of the GIFTI surface at `path`, in the file's
// order; `name` is used in messages. INVALID_ARGUMENT naming `name` and the
// problem for a file that is malformed, truncated or not GIFTI, a missing
// or misshapen pointset or triangle array, a data type other than those
// above, data that does not match its declared size, external-file data, or
// a negative index. Finite coordinates and indices below the vertex count
// are left to the mesh reader, which checks them for every format.
absl::StatusOr<TriangleSoup> ReadGiftiSurface(const std::string& path, std::string_view name);

// A GIFTI metric (x.func.gii) holding `values` as one NIFTI_INTENT_SHAPE
// float32 array, GZipBase64Binary, little-endian: the file's bytes
// (RESOURCE_EXHAUSTED if zlib cannot allocate).
// +inf stays +inf (IEEE float32 holds it; libgiftiio and nibabel read it
// back as inf).
absl::StatusOr<std::string> GiftiMetricBytes(absl::Span<const double> values);

}  // namespace geodesic

#endif  // GEODESIC_CORE_MESH_GIFTI_FILES_H_
