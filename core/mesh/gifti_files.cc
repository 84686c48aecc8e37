#include "core/mesh/gifti_files.h"

// Debian's gifti_io.h is C without extern "C" guards of its own.
extern "C" {
#include <gifti_io.h>
}
#include <expat.h>
#include <zlib.h>

#include <algorithm>
#include <bit>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <vector>

#include "absl/base/const_init.h"
#include "absl/cleanup/cleanup.h"
#include "absl/status/status.h"
#include "absl/strings/escaping.h"
#include "absl/strings/str_format.h"
#include "absl/synchronization/mutex.h"
#include "core/base/status.h"

namespace geodesic {
namespace {

static_assert(std::endian::native == std::endian::little,
              "GIFTI metrics are written as little-endian memory images");

// libgiftiio keeps its verbosity and its XML parser's state in globals: two
// reads at once (the daemon loads meshes on several threads) would share one
// parser.
ABSL_CONST_INIT absl::Mutex gifti_mu(absl::kConstInit);

struct GiftiImageFree {
  void operator()(gifti_image* image) const { gifti_free_image(image); }
};
using GiftiImage = std::unique_ptr<gifti_image, GiftiImageFree>;

// A file small enough to read can still declare an array of billions of
// values, which libgiftiio would allocate before decoding any: no encoding
// holds more than zlib's best ratio (about 1032:1) of data per file byte.
constexpr uint64_t kMaxGiftiBytesPerFileByte = 1100;

// libgiftiio prints expat's complaint about malformed XML to stderr whatever
// its verbosity, and says nothing else about it; checked here first, the
// daemon's log stays quiet and the message says where the file breaks.
absl::Status CheckWellFormedXml(const std::string& path, std::string_view name) {
  std::ifstream in(path, std::ios::binary);
  XML_Parser parser = XML_ParserCreate(nullptr);
  if (parser == nullptr) return absl::ResourceExhaustedError("cannot create an XML parser");
  absl::Cleanup free_parser = [parser] { XML_ParserFree(parser); };
  std::vector<char> buffer(1 << 16);
  bool done = false;
  while (!done) {
    in.read(buffer.data(), buffer.size());
    done = in.gcount() < static_cast<std::streamsize>(buffer.size());
    if (XML_Parse(parser, buffer.data(), static_cast<int>(in.gcount()), done) == XML_STATUS_OK) {
      continue;
    }
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: not a readable GIFTI file (malformed or truncated XML: %s at line %u)", name,
        XML_ErrorString(XML_GetErrorCode(parser)), XML_GetCurrentLineNumber(parser)));
  }
  return absl::OkStatus();
}

// Verbosity 0: the daemon's stderr is its log, and libgiftiio otherwise
// describes every problem there besides returning NULL.
GiftiImage ParseGifti(const std::string& path, bool read_data)
    ABSL_EXCLUSIVE_LOCKS_REQUIRED(gifti_mu) {
  gifti_set_verb(0);
  return GiftiImage(gifti_read_image(path.c_str(), read_data ? 1 : 0));
}

const giiDataArray* FindGiftiArray(const gifti_image& image, int intent) {
  if (image.darray == nullptr) return nullptr;
  for (int k = 0; k < image.numDA; ++k) {
    if (image.darray[k] != nullptr && image.darray[k]->intent == intent) return image.darray[k];
  }
  return nullptr;
}

struct GiftiArrayKind {
  int intent;
  const char* what;  // in messages: "pointset", "triangle"
  const char* intent_name;
  std::vector<int> datatypes;
  const char* datatype_names;
};

const GiftiArrayKind kGiftiPoints = {NIFTI_INTENT_POINTSET,
                                     "pointset",
                                     "NIFTI_INTENT_POINTSET",
                                     {NIFTI_TYPE_FLOAT32, NIFTI_TYPE_FLOAT64},
                                     "float32 or float64"};
const GiftiArrayKind kGiftiTriangles = {
    NIFTI_INTENT_TRIANGLE, "triangle", "NIFTI_INTENT_TRIANGLE", {NIFTI_TYPE_INT32}, "int32"};

// What can be checked before the data is read: present, N x 3, a known type
// and order, its data in this file, and no more of it than the file can hold.
absl::StatusOr<const giiDataArray*> CheckGiftiArray(const gifti_image& image,
                                                    const GiftiArrayKind& kind,
                                                    std::string_view name, uint64_t file_bytes) {
  const giiDataArray* da = FindGiftiArray(image, kind.intent);
  if (da == nullptr) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: no %s array (Intent=\"%s\"): not a GIFTI surface", name, kind.what, kind.intent_name));
  }
  if (da->encoding == GIFTI_ENCODING_EXTBIN || (da->ext_fname && da->ext_fname[0] != '\0')) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: the %s array's data is in an external file ('%s'), which is not read",
                        name, kind.what, absl::CHexEscape(da->ext_fname ? da->ext_fname : "")));
  }
  if (da->num_dim != 2 || da->dims[0] < 0 || da->dims[1] != 3) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: the %s array has %d dimensions (%d x %d), not N x 3", name, kind.what,
                        da->num_dim, da->dims[0], da->num_dim > 1 ? da->dims[1] : 1));
  }
  if (std::find(kind.datatypes.begin(), kind.datatypes.end(), da->datatype) ==
      kind.datatypes.end()) {
    const char* type = gifti_datatype2str(da->datatype);
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: the %s array holds %s, not %s", name, kind.what,
                        type ? type : "an unknown data type", kind.datatype_names));
  }
  if (da->ind_ord != GIFTI_IND_ORD_ROW_MAJOR && da->ind_ord != GIFTI_IND_ORD_COL_MAJOR) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: the %s array's ArrayIndexingOrder is neither RowMajorOrder nor ColumnMajorOrder", name,
        kind.what));
  }
  int nbyper = 0, swapsize = 0;
  gifti_datatype_sizes(da->datatype, &nbyper, &swapsize);
  const uint64_t bytes = uint64_t{3} * static_cast<uint64_t>(da->dims[0]) * nbyper;
  if (bytes > kMaxGiftiBytesPerFileByte * file_bytes) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: the %s array declares %d rows, more than its %u bytes can hold", name,
                        kind.what, da->dims[0], file_bytes));
  }
  return da;
}

// Element (row, col) of an N x 3 array, in either indexing order.
template <typename T>
T GiftiAt(const giiDataArray& da, int64_t row, int col) {
  const int64_t n = da.dims[0];
  const int64_t i = da.ind_ord == GIFTI_IND_ORD_COL_MAJOR ? col * n + row : row * 3 + col;
  T value;
  std::memcpy(&value, static_cast<const char*>(da.data) + i * sizeof(T), sizeof(T));
  return value;
}

absl::Status CheckGiftiData(const giiDataArray& da, const GiftiArrayKind& kind,
                            std::string_view name) {
  if (da.data == nullptr || da.nvals != int64_t{3} * da.dims[0]) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: the %s array's data could not be read (malformed or truncated)", name, kind.what));
  }
  return absl::OkStatus();
}

absl::StatusOr<TriangleSoup> GiftiToSoup(const giiDataArray& points, const giiDataArray& triangles,
                                         std::string_view name) {
  RETURN_IF_ERROR(CheckGiftiData(points, kGiftiPoints, name));
  RETURN_IF_ERROR(CheckGiftiData(triangles, kGiftiTriangles, name));
  TriangleSoup soup;
  soup.positions.resize(points.dims[0]);
  for (int64_t v = 0; v < points.dims[0]; ++v) {
    double x[3];
    for (int k = 0; k < 3; ++k) {
      x[k] = points.datatype == NIFTI_TYPE_FLOAT32 ? GiftiAt<float>(points, v, k)
                                                   : GiftiAt<double>(points, v, k);
    }
    soup.positions[v] = {x[0], x[1], x[2]};
  }
  soup.triangles.resize(triangles.dims[0]);
  for (int64_t f = 0; f < triangles.dims[0]; ++f) {
    for (int k = 0; k < 3; ++k) {
      const int32_t index = GiftiAt<int32_t>(triangles, f, k);
      if (index < 0) {
        return absl::InvalidArgumentError(
            absl::StrFormat("%s: face %d refers to vertex %d", name, f, index));
      }
      soup.triangles[f][k] = static_cast<VertexId>(index);
    }
  }
  return soup;
}

}  // namespace

absl::StatusOr<TriangleSoup> ReadGiftiSurface(const std::string& path, std::string_view name) {
  std::error_code ec;
  const uint64_t file_bytes = std::filesystem::file_size(path, ec);
  if (ec) {
    return absl::InvalidArgumentError(absl::StrFormat("%s: cannot read (%s)", name, ec.message()));
  }
  RETURN_IF_ERROR(CheckWellFormedXml(path, name));
  absl::MutexLock lock(&gifti_mu);
  // First without the data: external files, shapes and sizes are refused
  // before libgiftiio reads or allocates anything for them.
  for (bool read_data : {false, true}) {
    GiftiImage image = ParseGifti(path, read_data);
    if (image == nullptr) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s: not a readable GIFTI file (malformed, truncated or not GIFTI XML)", name));
    }
    ASSIGN_OR_RETURN(const giiDataArray* points,
                     CheckGiftiArray(*image, kGiftiPoints, name, file_bytes));
    ASSIGN_OR_RETURN(const giiDataArray* triangles,
                     CheckGiftiArray(*image, kGiftiTriangles, name, file_bytes));
    if (read_data) return GiftiToSoup(*points, *triangles, name);
  }
  return absl::InternalError("unreachable");
}

absl::StatusOr<std::string> GiftiMetricBytes(absl::Span<const double> values) {
  // A double beyond float32's range becomes inf, as +inf (unreached) stays.
  const std::vector<float> data(values.begin(), values.end());
  const uLong raw_bytes = data.size() * sizeof(float);
  uLongf packed_bytes = compressBound(raw_bytes);
  std::string packed(packed_bytes, '\0');
  if (compress2(reinterpret_cast<Bytef*>(packed.data()), &packed_bytes,
                reinterpret_cast<const Bytef*>(data.data()), raw_bytes,
                Z_DEFAULT_COMPRESSION) != Z_OK) {
    return absl::ResourceExhaustedError("cannot compress the GIFTI metric (zlib)");
  }
  packed.resize(packed_bytes);
  return absl::StrFormat(
      "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
      "<!DOCTYPE GIFTI SYSTEM \"http://www.nitrc.org/frs/download.php/115/gifti.dtd\">\n"
      "<GIFTI Version=\"1.0\" NumberOfDataArrays=\"1\">\n"
      "  <MetaData/>\n"
      "  <LabelTable/>\n"
      "  <DataArray Intent=\"NIFTI_INTENT_SHAPE\" DataType=\"NIFTI_TYPE_FLOAT32\" "
      "ArrayIndexingOrder=\"RowMajorOrder\" Dimensionality=\"1\" Dim0=\"%u\" "
      "Encoding=\"GZipBase64Binary\" Endian=\"LittleEndian\" ExternalFileName=\"\" "
      "ExternalFileOffset=\"\">\n"
      "    <MetaData>\n"
      "      <MD><Name><![CDATA[Name]]></Name><Value><![CDATA[geodesic distance]]></Value></MD>\n"
      "    </MetaData>\n"
      "    <Data>%s</Data>\n"
      "  </DataArray>\n"
      "</GIFTI>\n",
      data.size(), absl::Base64Escape(packed));
}

}  // namespace geodesic
