#include "core/mesh/gifti_files.h"

// Debian's gifti_io.h is C without extern "C" guards of its own.
extern "C" {
#include <gifti_io.h>
}
#include <expat.h>
#include <zlib.h>

#include <algorithm>
#include <bit>
#include <cctype>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <memory>
#include <sstream>
#include <vector>

#include "absl/base/const_init.h"
#include "absl/cleanup/cleanup.h"
#include "absl/status/status.h"
#include "absl/strings/escaping.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
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

// The Data text of each DataArray, in document order (libgiftiio's darray
// order), as expat reads it, and whether any array's data is elsewhere.
struct GiftiXmlScan {
  std::vector<std::string> data;
  int declared_arrays = -1;  // the GIFTI element's NumberOfDataArrays
  std::string problem;       // the first array libgiftiio must not see
  int in_array = 0;          // DataArray elements open
  bool in_data = false;
};

// What libgiftiio would refuse only with a complaint on stderr (or, for
// external data, not refuse at all: it opens an array's ExternalFileName
// even when told not to read data) in a DataArray's attributes, or "".
std::string DataArrayProblem(const XML_Char** attributes) {
  std::map<std::string, std::string> a;
  for (int k = 0; attributes[k] != nullptr && attributes[k + 1] != nullptr; k += 2) {
    a[attributes[k]] = attributes[k + 1];
  }
  if (a["Encoding"] == "ExternalFileBinary" || !a["ExternalFileName"].empty()) {
    return absl::StrFormat("its data is in an external file ('%s'), which is not read",
                           absl::CHexEscape(a["ExternalFileName"]));
  }
  if (a["Encoding"] != "ASCII" && a["Encoding"] != "Base64Binary" &&
      a["Encoding"] != "GZipBase64Binary") {
    return absl::StrFormat("its Encoding '%s' is not ASCII, Base64Binary or GZipBase64Binary",
                           absl::CHexEscape(a["Encoding"]));
  }
  int dimensions = 0;
  if (!absl::SimpleAtoi(a["Dimensionality"], &dimensions) || dimensions < 1 || dimensions > 6) {
    return absl::StrFormat("its Dimensionality '%s' is not 1 to 6",
                           absl::CHexEscape(a["Dimensionality"]));
  }
  int64_t values = 1;
  for (int k = 0; k < dimensions; ++k) {
    const std::string key = absl::StrCat("Dim", k);
    int size = 0;
    if (!absl::SimpleAtoi(a[key], &size) || size < 1) {
      return absl::StrFormat("its %s '%s' is not a positive integer", key,
                             absl::CHexEscape(a[key]));
    }
    values *= size;
    if (values > std::numeric_limits<int32_t>::max()) {
      return "its dimensions multiply to more than 2^31 - 1 values";
    }
  }
  return "";
}

void ScanStart(void* user, const XML_Char* element, const XML_Char** attributes) {
  auto* scan = static_cast<GiftiXmlScan*>(user);
  if (std::strcmp(element, "GIFTI") == 0) {
    for (int k = 0; attributes[k] != nullptr && attributes[k + 1] != nullptr; k += 2) {
      if (std::strcmp(attributes[k], "NumberOfDataArrays") == 0 &&
          !absl::SimpleAtoi(attributes[k + 1], &scan->declared_arrays)) {
        scan->declared_arrays = -2;
      }
    }
  } else if (std::strcmp(element, "DataArray") == 0) {
    ++scan->in_array;
    scan->data.emplace_back();
    if (std::string problem = DataArrayProblem(attributes);
        !problem.empty() && scan->problem.empty()) {
      scan->problem = absl::StrFormat("DataArray %u: %s", scan->data.size() - 1, problem);
    }
  } else if (std::strcmp(element, "Data") == 0 && scan->in_array > 0) {
    scan->in_data = true;
  }
}

void ScanEnd(void* user, const XML_Char* element) {
  auto* scan = static_cast<GiftiXmlScan*>(user);
  if (std::strcmp(element, "DataArray") == 0) --scan->in_array;
  if (std::strcmp(element, "Data") == 0) scan->in_data = false;
}

void ScanText(void* user, const XML_Char* text, int length) {
  auto* scan = static_cast<GiftiXmlScan*>(user);
  if (scan->in_data) scan->data.back().append(text, length);
}

// libgiftiio prints expat's complaint about malformed XML to stderr whatever
// its verbosity, and says nothing else about it; checked here first, the
// daemon's log stays quiet and the message says where the file breaks.
absl::StatusOr<GiftiXmlScan> ScanGiftiXml(const std::string& path, std::string_view name) {
  std::ifstream in(path, std::ios::binary);
  XML_Parser parser = XML_ParserCreate(nullptr);
  if (parser == nullptr) return absl::ResourceExhaustedError("cannot create an XML parser");
  absl::Cleanup free_parser = [parser] { XML_ParserFree(parser); };
  GiftiXmlScan scan;
  XML_SetUserData(parser, &scan);
  XML_SetElementHandler(parser, ScanStart, ScanEnd);
  XML_SetCharacterDataHandler(parser, ScanText);
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
  if (!scan.problem.empty()) {
    return absl::InvalidArgumentError(absl::StrFormat("%s: %s", name, scan.problem));
  }
  if (scan.declared_arrays == -1) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: not a GIFTI file (no GIFTI element with NumberOfDataArrays)", name));
  }
  if (scan.declared_arrays != static_cast<int>(scan.data.size())) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: NumberOfDataArrays says %d, but the file has %u DataArray elements",
                        name, scan.declared_arrays, scan.data.size()));
  }
  return scan;
}

// Verbosity 0: the daemon's stderr is its log, and libgiftiio otherwise
// describes every problem there besides returning NULL.
GiftiImage ParseGifti(const std::string& path, bool read_data)
    ABSL_EXCLUSIVE_LOCKS_REQUIRED(gifti_mu) {
  gifti_set_verb(0);
  return GiftiImage(gifti_read_image(path.c_str(), read_data ? 1 : 0));
}

// The index of the first array with `intent`, or -1.
int FindGiftiArray(const gifti_image& image, int intent) {
  if (image.darray == nullptr) return -1;
  for (int k = 0; k < image.numDA; ++k) {
    if (image.darray[k] != nullptr && image.darray[k]->intent == intent) return k;
  }
  return -1;
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
// GIFTI names int32 only, but nibabel writes numpy's default int64 (and
// uint32 comes from other writers) without a word: read them all.
const GiftiArrayKind kGiftiTriangles = {NIFTI_INTENT_TRIANGLE,
                                        "triangle",
                                        "NIFTI_INTENT_TRIANGLE",
                                        {NIFTI_TYPE_INT32, NIFTI_TYPE_INT64, NIFTI_TYPE_UINT32},
                                        "int32, int64 or uint32"};

// What can be checked before the data is read: present, N x 3, a known type
// and order, its data in this file, and no more of it than the file can hold.
absl::StatusOr<int> CheckGiftiArray(const gifti_image& image, const GiftiArrayKind& kind,
                                    std::string_view name, uint64_t file_bytes) {
  const int index = FindGiftiArray(image, kind.intent);
  if (index < 0) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: no %s array (Intent=\"%s\"): not a GIFTI surface", name, kind.what, kind.intent_name));
  }
  const giiDataArray* da = image.darray[index];
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
  return index;
}

// The number of values `text` holds in `da`'s encoding, or an error saying
// why it holds none.
absl::StatusOr<int64_t> CountGiftiValues(const giiDataArray& da, const std::string& text,
                                         size_t value_bytes, int64_t expected) {
  if (da.encoding == GIFTI_ENCODING_ASCII) {
    int64_t count = 0;
    std::istringstream words(text);
    for (std::string word; words >> word; ++count) {
      char* end = nullptr;
      std::strtod(word.c_str(), &end);
      if (end != word.c_str() + word.size()) {
        return absl::InvalidArgumentError(
            absl::StrFormat("value %d is '%s', not a number", count, absl::CHexEscape(word)));
      }
    }
    return count;
  }
  std::string base64 = text;
  std::erase_if(base64, [](char c) { return std::isspace(static_cast<unsigned char>(c)); });
  std::string bytes;
  // Unpadded base64 absl accepts, but libgiftiio drops its last bytes.
  if (base64.size() % 4 != 0 || !absl::Base64Unescape(base64, &bytes)) {
    return absl::InvalidArgumentError("not base64 (padded to a multiple of 4 characters)");
  }
  if (da.encoding == GIFTI_ENCODING_B64GZ) {
    // One byte more than expected: room to notice more data than declared.
    std::string raw(expected * value_bytes + 1, '\0');
    uLongf size = raw.size();
    if (uncompress(reinterpret_cast<Bytef*>(raw.data()), &size,
                   reinterpret_cast<const Bytef*>(bytes.data()), bytes.size()) != Z_OK) {
      return absl::InvalidArgumentError("not zlib-compressed, or more data than declared");
    }
    return static_cast<int64_t>(size / value_bytes);
  }
  return static_cast<int64_t>(bytes.size() / value_bytes);
}

// libgiftiio fills data that is short of the declared size with zeros (a
// torn array would read as vertices at the origin) and decodes garbage with
// a complaint on stderr only; each array's data is measured here first.
absl::Status CheckGiftiDataText(const giiDataArray& da, const GiftiArrayKind& kind,
                                const std::string& text, std::string_view name) {
  if (da.encoding != GIFTI_ENCODING_ASCII && da.endian != GIFTI_ENDIAN_LITTLE &&
      da.endian != GIFTI_ENDIAN_BIG) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: the %s array's Endian is missing, or neither LittleEndian nor BigEndian", name,
        kind.what));
  }
  int value_bytes = 0, swapsize = 0;
  gifti_datatype_sizes(da.datatype, &value_bytes, &swapsize);
  const int64_t expected = int64_t{3} * da.dims[0];
  auto count = CountGiftiValues(da, text, value_bytes, expected);
  if (!count.ok()) {
    return absl::InvalidArgumentError(absl::StrFormat("%s: the %s array's data is unreadable: %s",
                                                      name, kind.what, count.status().message()));
  }
  if (*count != expected) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: the %s array declares %d values but its data holds %d (truncated or "
                        "malformed)",
                        name, kind.what, expected, *count));
  }
  return absl::OkStatus();
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

// Corner `col` of triangle `row`, widened from the array's integer type.
int64_t GiftiIndexAt(const giiDataArray& da, int64_t row, int col) {
  switch (da.datatype) {
    case NIFTI_TYPE_INT64:
      return GiftiAt<int64_t>(da, row, col);
    case NIFTI_TYPE_UINT32:
      return GiftiAt<uint32_t>(da, row, col);
    default:
      return GiftiAt<int32_t>(da, row, col);
  }
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
      const int64_t index = GiftiIndexAt(triangles, f, k);
      if (index < 0 || index > std::numeric_limits<VertexId>::max()) {
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
  ASSIGN_OR_RETURN(GiftiXmlScan scan, ScanGiftiXml(path, name));
  const auto unreadable = [name] {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: not a readable GIFTI file (malformed, truncated or not GIFTI XML)", name));
  };
  absl::MutexLock lock(&gifti_mu);
  // First without the data: shapes and sizes are checked, and each array's
  // data measured against them, before libgiftiio decodes or allocates.
  GiftiImage header = ParseGifti(path, /*read_data=*/false);
  if (header == nullptr) return unreadable();
  ASSIGN_OR_RETURN(int points, CheckGiftiArray(*header, kGiftiPoints, name, file_bytes));
  ASSIGN_OR_RETURN(int triangles, CheckGiftiArray(*header, kGiftiTriangles, name, file_bytes));
  if (scan.data.size() != static_cast<size_t>(header->numDA)) return unreadable();
  RETURN_IF_ERROR(
      CheckGiftiDataText(*header->darray[points], kGiftiPoints, scan.data[points], name));
  RETURN_IF_ERROR(
      CheckGiftiDataText(*header->darray[triangles], kGiftiTriangles, scan.data[triangles], name));
  std::vector<std::string>().swap(scan.data);
  GiftiImage image = ParseGifti(path, /*read_data=*/true);
  if (image == nullptr || image->numDA != header->numDA) return unreadable();
  ASSIGN_OR_RETURN(points, CheckGiftiArray(*image, kGiftiPoints, name, file_bytes));
  ASSIGN_OR_RETURN(triangles, CheckGiftiArray(*image, kGiftiTriangles, name, file_bytes));
  return GiftiToSoup(*image->darray[points], *image->darray[triangles], name);
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
