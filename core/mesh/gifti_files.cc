#include "core/mesh/gifti_files.h"

#include <expat.h>
#include <zlib.h>

#include <algorithm>
#include <bit>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <string>
#include <type_traits>
#include <vector>

#include "absl/cleanup/cleanup.h"
#include "absl/status/status.h"
#include "absl/strings/escaping.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "absl/strings/str_split.h"
#include "absl/strings/string_view.h"
#include "core/base/status.h"

namespace geodesic {
namespace {

static_assert(std::endian::native == std::endian::little,
              "GIFTI data is decoded into, and metrics written as, little-endian memory images");

// One XML_Parse call takes an int length.
constexpr uint64_t kMaxGiftiFileBytes = std::numeric_limits<int>::max();
// No GIFTI attribute needs more; a longer one is an attack or garbage.
constexpr size_t kMaxAttributeChars = 64 * 1024;
// Deflate's best ratio: a 258-byte match coded in 2 bits, 1032:1.
constexpr uint64_t kMaxZlibRatio = 1032;

// At most `max` characters of untrusted text, escaped, for a message.
std::string Shown(absl::string_view text, size_t max = 60) {
  return absl::CHexEscape(text.substr(0, max)) + (text.size() > max ? "..." : "");
}

// GIFTI 1.0's elements, each beside the element it may appear in (MetaData
// in two). The schema has no recursion, so checking each element as it opens
// also bounds the nesting (five deep): libgiftiio's callbacks crashed on
// Data or MD out of place, MetaData in a Label, and deep nesting.
struct SchemaEdge {
  absl::string_view parent, child;
};
constexpr SchemaEdge kGiftiSchema[] = {
    {"GIFTI", "MetaData"},
    {"GIFTI", "LabelTable"},
    {"GIFTI", "DataArray"},
    {"MetaData", "MD"},
    {"MD", "Name"},
    {"MD", "Value"},
    {"LabelTable", "Label"},
    {"DataArray", "MetaData"},
    {"DataArray", "CoordinateSystemTransformMatrix"},
    {"DataArray", "Data"},
    {"CoordinateSystemTransformMatrix", "DataSpace"},
    {"CoordinateSystemTransformMatrix", "TransformedSpace"},
    {"CoordinateSystemTransformMatrix", "MatrixData"},
};

// Why `child` may not open inside `parent` ("" for the root), or "".
std::string SchemaProblem(absl::string_view parent, absl::string_view child) {
  if (parent.empty()) {
    if (child == "GIFTI") return "";
    return absl::StrFormat("the root element is <%s>, not <GIFTI>: not a GIFTI file", Shown(child));
  }
  bool known = child == "GIFTI";
  for (const SchemaEdge& edge : kGiftiSchema) {
    if (edge.parent == parent && edge.child == child) return "";
    known = known || edge.child == child;
  }
  if (!known) return absl::StrFormat("an unknown element <%s> inside <%s>", Shown(child), parent);
  std::vector<std::string> allowed;
  for (const SchemaEdge& edge : kGiftiSchema) {
    if (edge.parent == parent) allowed.push_back(absl::StrCat("<", edge.child, ">"));
  }
  if (allowed.empty()) {
    return absl::StrFormat("a <%s> element inside <%s>, which holds only text", child, parent);
  }
  return absl::StrFormat("a <%s> element inside <%s>, where GIFTI allows only %s", child, parent,
                         absl::StrJoin(allowed, ", "));
}

// `key`'s value among expat's name/value pairs, or "".
absl::string_view Attribute(const XML_Char** attributes, absl::string_view key) {
  for (int k = 0; attributes[k] != nullptr; k += 2) {
    if (key == attributes[k]) return attributes[k + 1];
  }
  return "";
}

enum class ValueType { kFloat32, kFloat64, kInt32, kInt64, kUint32 };
struct TypeName {
  absl::string_view name;  // the DataType attribute
  ValueType type;
  int bytes;
};
constexpr TypeName kTypeNames[] = {{"NIFTI_TYPE_FLOAT32", ValueType::kFloat32, 4},
                                   {"NIFTI_TYPE_FLOAT64", ValueType::kFloat64, 8},
                                   {"NIFTI_TYPE_INT32", ValueType::kInt32, 4},
                                   {"NIFTI_TYPE_INT64", ValueType::kInt64, 8},
                                   {"NIFTI_TYPE_UINT32", ValueType::kUint32, 4}};

// What a DataArray's attributes declare, as far as a surface needs them.
struct ArrayHeader {
  int index = -1;  // among the file's DataArrays; -1 until the array is found
  std::string intent, datatype, encoding, endian, order;
  std::vector<int> dims;
  int64_t values = 0;  // the product of dims
};

// The first DataArray of one intent: its header, then its Data's text, then
// its values (the bytes of its type, in the file's order, little-endian).
struct SurfaceArray {
  ArrayHeader header;
  TypeName type{};
  bool column_major = false;
  std::string text;
  std::string values;
  uint64_t declared_bytes() const { return header.values * type.bytes; }
};

struct ArrayKind {
  const char* what;  // in messages: "pointset", "triangle"
  absl::string_view intent;
  absl::string_view types[3];  // DataType names read; "" for none
  const char* type_names;
};
constexpr ArrayKind kPoints = {"pointset",
                               "NIFTI_INTENT_POINTSET",
                               {"NIFTI_TYPE_FLOAT32", "NIFTI_TYPE_FLOAT64", ""},
                               "float32 or float64"};
// GIFTI names int32 only, but nibabel writes numpy's default int64 (and
// uint32 comes from other writers) without a word: read them all.
constexpr ArrayKind kTriangles = {"triangle",
                                  "NIFTI_INTENT_TRIANGLE",
                                  {"NIFTI_TYPE_INT32", "NIFTI_TYPE_INT64", "NIFTI_TYPE_UINT32"},
                                  "int32, int64 or uint32"};

// What every DataArray must declare, surface array or not: its data in this
// file (a file naming another file on the server's disk must not make it read
// that file), a known encoding, and 1 to 6 positive dimensions.
absl::StatusOr<ArrayHeader> ReadArrayHeader(const XML_Char** attributes) {
  ArrayHeader h;
  h.encoding = std::string(Attribute(attributes, "Encoding"));
  const absl::string_view external = Attribute(attributes, "ExternalFileName");
  if (h.encoding == "ExternalFileBinary" || !external.empty()) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "its data is in an external file ('%s'), which is not read", Shown(external, 200)));
  }
  if (h.encoding != "ASCII" && h.encoding != "Base64Binary" && h.encoding != "GZipBase64Binary") {
    return absl::InvalidArgumentError(absl::StrFormat(
        "its Encoding '%s' is not ASCII, Base64Binary or GZipBase64Binary", Shown(h.encoding)));
  }
  const absl::string_view dimensionality = Attribute(attributes, "Dimensionality");
  int dimensions = 0;
  if (!absl::SimpleAtoi(dimensionality, &dimensions) || dimensions < 1 || dimensions > 6) {
    return absl::InvalidArgumentError(
        absl::StrFormat("its Dimensionality '%s' is not 1 to 6", Shown(dimensionality)));
  }
  h.values = 1;
  for (int k = 0; k < dimensions; ++k) {
    const std::string key = absl::StrCat("Dim", k);
    const absl::string_view text = Attribute(attributes, key);
    int size = 0;
    if (!absl::SimpleAtoi(text, &size) || size < 1) {
      return absl::InvalidArgumentError(
          absl::StrFormat("its %s '%s' is not a positive integer", key, Shown(text)));
    }
    h.dims.push_back(size);
    h.values *= size;
    if (h.values > std::numeric_limits<int32_t>::max()) {
      return absl::InvalidArgumentError("its dimensions multiply to more than 2^31 - 1 values");
    }
  }
  h.intent = std::string(Attribute(attributes, "Intent"));
  h.datatype = std::string(Attribute(attributes, "DataType"));
  h.endian = std::string(Attribute(attributes, "Endian"));
  h.order = std::string(Attribute(attributes, "ArrayIndexingOrder"));
  return h;
}

// The DataType `datatype`, if arrays of `kind` are read in it, or null.
const TypeName* ReadType(const ArrayKind& kind, absl::string_view datatype) {
  const auto& read = kind.types;
  if (datatype.empty() || std::find(std::begin(read), std::end(read), datatype) == std::end(read)) {
    return nullptr;
  }
  for (const TypeName& t : kTypeNames) {
    if (t.name == datatype) return &t;
  }
  return nullptr;
}

// A surface array's shape, type, order and byte order, or why it is not one.
absl::StatusOr<TypeName> CheckSurfaceArray(const ArrayHeader& h, const ArrayKind& kind) {
  if (h.dims.size() != 2 || h.dims[1] != 3) {
    return absl::InvalidArgumentError(
        absl::StrFormat("the %s array has %d dimensions (%d x %d), not N x 3", kind.what,
                        h.dims.size(), h.dims[0], h.dims.size() > 1 ? h.dims[1] : 1));
  }
  const TypeName* type = ReadType(kind, h.datatype);
  if (type == nullptr) {
    return absl::InvalidArgumentError(
        absl::StrFormat("the %s array holds %s, not %s", kind.what,
                        h.datatype.empty() ? "no DataType" : Shown(h.datatype), kind.type_names));
  }
  if (h.order != "RowMajorOrder" && h.order != "ColumnMajorOrder") {
    return absl::InvalidArgumentError(absl::StrFormat(
        "the %s array's ArrayIndexingOrder is neither RowMajorOrder nor ColumnMajorOrder",
        kind.what));
  }
  if (h.encoding != "ASCII" && h.endian != "LittleEndian" && h.endian != "BigEndian") {
    return absl::InvalidArgumentError(absl::StrFormat(
        "the %s array's Endian is missing, or neither LittleEndian nor BigEndian", kind.what));
  }
  return *type;
}

// The expat pass: the schema checked as each element opens, each DataArray's
// header as it opens (the surface arrays' declared sizes against the budget
// before a byte of their data is kept), and the Data text of the first
// pointset and triangle arrays kept; all other text is dropped.
struct GiftiParse {
  XML_Parser parser = nullptr;
  std::string_view name;  // the file, in messages
  uint64_t max_decoded_bytes = 0;
  absl::Status status;            // the first refusal; parsing stops there
  std::vector<std::string> open;  // the elements open, from the root
  int64_t declared_arrays = -1;   // the GIFTI element's NumberOfDataArrays
  int arrays = 0;                 // DataArray elements opened
  bool array_has_data = false;    // whether the open DataArray had a Data
  SurfaceArray* array = nullptr;  // the open DataArray, if a surface array
  std::string* data = nullptr;    // where the open Data's text goes, if kept
  SurfaceArray points, triangles;

  absl::Status Invalid(absl::string_view problem) const {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s line %u: %s", name, XML_GetCurrentLineNumber(parser), problem));
  }
};

absl::Status ReadGiftiAttributes(GiftiParse& p, const XML_Char** attributes) {
  const absl::string_view count = Attribute(attributes, "NumberOfDataArrays");
  if (count.empty()) {
    return p.Invalid("not a GIFTI file (no GIFTI element with NumberOfDataArrays)");
  }
  if (!absl::SimpleAtoi(count, &p.declared_arrays) || p.declared_arrays < 0) {
    return p.Invalid(absl::StrFormat("NumberOfDataArrays '%s' is not a count", Shown(count)));
  }
  return absl::OkStatus();
}

// Refused as the arrays open, so that a small file declaring gigabytes is
// turned away before anything is allocated for it.
absl::Status CheckBudget(const GiftiParse& p, const ArrayKind& kind) {
  const uint64_t total = p.points.declared_bytes() + p.triangles.declared_bytes();
  if (p.max_decoded_bytes == 0 || total <= p.max_decoded_bytes) return absl::OkStatus();
  const SurfaceArray& a = &kind == &kPoints ? p.points : p.triangles;
  return absl::ResourceExhaustedError(absl::StrFormat(
      "%s: the %s array (DataArray %d) declares %u bytes of data, which brings the surface's "
      "arrays to %u, more than the limit of %u bytes",
      p.name, kind.what, a.header.index, a.declared_bytes(), total, p.max_decoded_bytes));
}

absl::Status OpenDataArray(GiftiParse& p, const XML_Char** attributes) {
  const int index = p.arrays++;
  p.array_has_data = false;
  p.array = nullptr;
  absl::StatusOr<ArrayHeader> header = ReadArrayHeader(attributes);
  if (!header.ok()) {
    return p.Invalid(absl::StrFormat("DataArray %d: %s", index, header.status().message()));
  }
  const ArrayKind* kind = nullptr;
  if (header->intent == kPoints.intent && p.points.header.index < 0) kind = &kPoints;
  if (header->intent == kTriangles.intent && p.triangles.header.index < 0) kind = &kTriangles;
  if (kind == nullptr) return absl::OkStatus();  // not read: checked above, then skipped
  absl::StatusOr<TypeName> type = CheckSurfaceArray(*header, *kind);
  if (!type.ok()) return p.Invalid(type.status().message());
  SurfaceArray& array = kind == &kPoints ? p.points : p.triangles;
  array.header = *std::move(header);
  array.header.index = index;
  array.type = *type;
  array.column_major = array.header.order == "ColumnMajorOrder";
  p.array = &array;
  return CheckBudget(p, *kind);
}

absl::Status OpenElement(GiftiParse& p, absl::string_view element, const XML_Char** attributes) {
  const absl::string_view parent = p.open.empty() ? "" : absl::string_view(p.open.back());
  if (std::string problem = SchemaProblem(parent, element); !problem.empty()) {
    return p.Invalid(problem);
  }
  for (int k = 0; attributes[k] != nullptr; k += 2) {
    if (std::strlen(attributes[k + 1]) > kMaxAttributeChars) {
      return p.Invalid(absl::StrFormat("<%s>'s attribute %s is %u characters long, more than %u",
                                       element, Shown(attributes[k]),
                                       std::strlen(attributes[k + 1]), kMaxAttributeChars));
    }
  }
  p.open.emplace_back(element);
  if (element == "GIFTI") return ReadGiftiAttributes(p, attributes);
  if (element == "DataArray") return OpenDataArray(p, attributes);
  if (element == "Data") {
    if (p.array_has_data) return p.Invalid("a second <Data> element in one DataArray");
    p.array_has_data = true;
    if (p.array != nullptr) p.data = &p.array->text;
  }
  return absl::OkStatus();
}

// Expat may still call a handler or two after XML_StopParser: each returns
// at once once a refusal is recorded.
void OnStart(void* user, const XML_Char* element, const XML_Char** attributes) {
  auto& p = *static_cast<GiftiParse*>(user);
  if (!p.status.ok()) return;
  p.status = OpenElement(p, element, attributes);
  if (!p.status.ok()) XML_StopParser(p.parser, XML_FALSE);
}

void OnEnd(void* user, const XML_Char* element) {
  auto& p = *static_cast<GiftiParse*>(user);
  if (!p.status.ok() || p.open.empty()) return;
  p.open.pop_back();
  if (std::strcmp(element, "Data") == 0) p.data = nullptr;
  if (std::strcmp(element, "DataArray") == 0) p.array = nullptr;
}

void OnText(void* user, const XML_Char* text, int length) {
  auto& p = *static_cast<GiftiParse*>(user);
  if (p.status.ok() && p.data != nullptr) p.data->append(text, length);
}

// GIFTI has no use for entities, and refusing their declarations leaves no
// room for expansion tricks, whatever expat's own limits.
void OnEntityDeclaration(void* user, const XML_Char* entity, int, const XML_Char*, int,
                         const XML_Char*, const XML_Char*, const XML_Char*, const XML_Char*) {
  auto& p = *static_cast<GiftiParse*>(user);
  if (!p.status.ok()) return;
  p.status =
      p.Invalid(absl::StrFormat("an entity declaration (%s): GIFTI has none", Shown(entity)));
  XML_StopParser(p.parser, XML_FALSE);
}

// The whole buffer in one XML_Parse call: expat 2.5 re-scans a large token
// from its start on every call, which made a 16 MB attribute fed in 64 KiB
// pieces take quadratic time.
absl::Status ParseGiftiXml(absl::string_view bytes, GiftiParse& p) {
  if (bytes.size() > kMaxGiftiFileBytes) {
    return absl::ResourceExhaustedError(
        absl::StrFormat("%s: %u bytes, more than the %u a GIFTI file may have", p.name,
                        bytes.size(), kMaxGiftiFileBytes));
  }
  p.parser = XML_ParserCreate(nullptr);
  if (p.parser == nullptr) return absl::ResourceExhaustedError("cannot create an XML parser");
  absl::Cleanup free_parser = [&p] { XML_ParserFree(p.parser); };
  XML_SetUserData(p.parser, &p);
  XML_SetElementHandler(p.parser, OnStart, OnEnd);
  XML_SetCharacterDataHandler(p.parser, OnText);
  XML_SetEntityDeclHandler(p.parser, OnEntityDeclaration);
  const bool parsed = XML_Parse(p.parser, bytes.data(), static_cast<int>(bytes.size()),
                                /*isFinal=*/XML_TRUE) == XML_STATUS_OK;
  RETURN_IF_ERROR(p.status);
  if (!parsed) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: not a readable GIFTI file (malformed or truncated XML: %s at line %u)", p.name,
        XML_ErrorString(XML_GetErrorCode(p.parser)), XML_GetCurrentLineNumber(p.parser)));
  }
  if (p.declared_arrays != p.arrays) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: NumberOfDataArrays says %d, but the file has %d DataArray elements",
                        p.name, p.declared_arrays, p.arrays));
  }
  for (const ArrayKind* kind : {&kPoints, &kTriangles}) {
    if ((kind == &kPoints ? p.points : p.triangles).header.index < 0) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s: no %s array (Intent=\"%s\"): not a GIFTI surface", p.name,
                          kind->what, kind->intent));
    }
  }
  return absl::OkStatus();
}

absl::Status Unreadable(absl::string_view who, absl::string_view why) {
  return absl::InvalidArgumentError(absl::StrFormat("%s's data is unreadable: %s", who, why));
}

absl::Status Miscounted(absl::string_view who, int64_t declared, uint64_t held) {
  return absl::InvalidArgumentError(absl::StrFormat(
      "%s declares %d values but its data holds %u (truncated or malformed)", who, declared, held));
}

absl::Status Overdeclared(absl::string_view who, const SurfaceArray& a, uint64_t units,
                          const char* of_what) {
  return absl::InvalidArgumentError(
      absl::StrFormat("%s declares %d values (%u bytes), more than its %u %s can hold", who,
                      a.header.values, a.declared_bytes(), units, of_what));
}

bool IsXmlSpace(char c) { return c == ' ' || c == '\t' || c == '\n' || c == '\r'; }

// One ASCII value parsed as T and stored at `out`; false if it is not one.
template <typename T>
bool StoreAscii(absl::string_view word, char* out) {
  T value{};
  bool ok = false;
  if constexpr (std::is_same_v<T, float>) {
    ok = absl::SimpleAtof(word, &value);
  } else if constexpr (std::is_same_v<T, double>) {
    ok = absl::SimpleAtod(word, &value);
  } else {
    ok = absl::SimpleAtoi(word, &value);
  }
  std::memcpy(out, &value, sizeof value);
  return ok;
}

bool StoreAsciiValue(absl::string_view word, ValueType type, char* out) {
  switch (type) {
    case ValueType::kFloat32:
      return StoreAscii<float>(word, out);
    case ValueType::kFloat64:
      return StoreAscii<double>(word, out);
    case ValueType::kInt32:
      return StoreAscii<int32_t>(word, out);
    case ValueType::kInt64:
      return StoreAscii<int64_t>(word, out);
    case ValueType::kUint32:
      return StoreAscii<uint32_t>(word, out);
  }
  return false;
}

// The values are counted before their buffer is allocated: a value takes at
// least one character, so a declaration beyond the text's length is refused
// outright, and any other miscount without parsing a number.
absl::Status DecodeAscii(SurfaceArray& a, absl::string_view who) {
  if (static_cast<uint64_t>(a.header.values) > a.text.size()) {
    return Overdeclared(who, a, a.text.size(), "characters of ASCII data");
  }
  const auto words = absl::StrSplit(a.text, absl::ByAnyChar(" \t\n\r"), absl::SkipEmpty());
  const int64_t count = std::distance(words.begin(), words.end());
  if (count != a.header.values) return Miscounted(who, a.header.values, count);
  a.values.assign(a.declared_bytes(), '\0');
  int64_t k = 0;
  for (absl::string_view word : words) {
    if (!StoreAsciiValue(word, a.type.type, a.values.data() + k * a.type.bytes)) {
      return Unreadable(who, absl::StrFormat("value %d is '%s', not a number of type %s", k,
                                             Shown(word), a.type.name));
    }
    ++k;
  }
  return absl::OkStatus();
}

// Streaming, into exactly the declared size: data beyond it is noticed in a
// one-byte scratch buffer rather than inflated.
absl::Status Inflate(absl::string_view compressed, SurfaceArray& a, absl::string_view who) {
  z_stream z{};
  if (inflateInit2(&z, 15 + 32) != Z_OK) {  // zlib or gzip framing
    return absl::ResourceExhaustedError("cannot start zlib");
  }
  absl::Cleanup end = [&z] { inflateEnd(&z); };
  a.values.assign(a.declared_bytes(), '\0');
  z.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(compressed.data()));
  z.avail_in = static_cast<uInt>(compressed.size());
  uint64_t done = 0;
  int rc = Z_OK;
  while (rc == Z_OK && done < a.values.size()) {
    const uInt chunk = static_cast<uInt>(std::min<uint64_t>(a.values.size() - done, 1u << 30));
    z.next_out = reinterpret_cast<Bytef*>(a.values.data() + done);
    z.avail_out = chunk;
    rc = inflate(&z, Z_NO_FLUSH);
    done += chunk - z.avail_out;
  }
  if (rc == Z_OK) {  // all declared bytes are in: the stream must end here
    Bytef extra;
    z.next_out = &extra;
    z.avail_out = 1;
    rc = inflate(&z, Z_NO_FLUSH);
    if (z.avail_out == 0) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s declares %d values but its data holds more", who, a.header.values));
    }
  }
  if (rc == Z_MEM_ERROR) return absl::ResourceExhaustedError("zlib ran out of memory");
  if (rc == Z_BUF_ERROR) return Unreadable(who, "not zlib-compressed, or its stream is truncated");
  if (rc != Z_STREAM_END) {
    return Unreadable(who, absl::StrCat("not zlib-compressed (", z.msg ? z.msg : "", ")"));
  }
  if (done != a.values.size()) return Miscounted(who, a.header.values, done / a.type.bytes);
  return absl::OkStatus();
}

// Base64Binary decodes to 3/4 of its text; GZipBase64Binary to at most
// kMaxZlibRatio times that, which bounds a declaration when no budget does.
absl::Status DecodeBinary(SurfaceArray& a, absl::string_view who) {
  std::erase_if(a.text, IsXmlSpace);
  std::string bytes;
  // Unpadded base64 absl accepts, but other readers drop its last bytes.
  if (a.text.size() % 4 != 0 || !absl::Base64Unescape(a.text, &bytes)) {
    return Unreadable(who, "not base64 (padded to a multiple of 4 characters)");
  }
  std::string().swap(a.text);
  if (a.header.encoding == "Base64Binary") {
    if (bytes.size() != a.declared_bytes()) {
      return Miscounted(who, a.header.values, bytes.size() / a.type.bytes);
    }
    a.values = std::move(bytes);
  } else {
    if (a.declared_bytes() > kMaxZlibRatio * bytes.size()) {
      return Overdeclared(who, a, bytes.size(), "bytes of compressed data");
    }
    RETURN_IF_ERROR(Inflate(bytes, a, who));
  }
  if (a.header.endian == "BigEndian") {
    for (size_t at = 0; at < a.values.size(); at += a.type.bytes) {
      std::reverse(a.values.begin() + at, a.values.begin() + at + a.type.bytes);
    }
  }
  return absl::OkStatus();
}

absl::Status DecodeArray(SurfaceArray& a, const ArrayKind& kind, std::string_view name) {
  const std::string who = absl::StrFormat("%s: the %s array", name, kind.what);
  absl::Status s = a.header.encoding == "ASCII" ? DecodeAscii(a, who) : DecodeBinary(a, who);
  std::string().swap(a.text);
  return s;
}

// Element (row, col) of an N x 3 array, in either indexing order.
template <typename T>
T ValueAt(const SurfaceArray& a, int64_t row, int col) {
  const int64_t n = a.header.dims[0];
  const int64_t i = a.column_major ? col * n + row : row * 3 + col;
  T value;
  std::memcpy(&value, a.values.data() + i * sizeof(T), sizeof(T));
  return value;
}

// Corner `col` of triangle `row`, widened from the array's integer type.
int64_t IndexAt(const SurfaceArray& a, int64_t row, int col) {
  switch (a.type.type) {
    case ValueType::kInt64:
      return ValueAt<int64_t>(a, row, col);
    case ValueType::kUint32:
      return ValueAt<uint32_t>(a, row, col);
    default:
      return ValueAt<int32_t>(a, row, col);
  }
}

absl::StatusOr<TriangleSoup> ToSoup(const SurfaceArray& points, const SurfaceArray& triangles,
                                    std::string_view name) {
  TriangleSoup soup;
  soup.positions.resize(points.header.dims[0]);
  const bool float32 = points.type.type == ValueType::kFloat32;
  for (int64_t v = 0; v < points.header.dims[0]; ++v) {
    double x[3];
    for (int k = 0; k < 3; ++k) {
      x[k] = float32 ? ValueAt<float>(points, v, k) : ValueAt<double>(points, v, k);
    }
    soup.positions[v] = {x[0], x[1], x[2]};
  }
  soup.triangles.resize(triangles.header.dims[0]);
  for (int64_t f = 0; f < triangles.header.dims[0]; ++f) {
    for (int k = 0; k < 3; ++k) {
      const int64_t index = IndexAt(triangles, f, k);
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

absl::StatusOr<TriangleSoup> ReadGiftiSurfaceFromMemory(std::string_view bytes,
                                                        std::string_view name,
                                                        uint64_t max_decoded_bytes) {
  GiftiParse p;
  p.name = name;
  p.max_decoded_bytes = max_decoded_bytes;
  RETURN_IF_ERROR(ParseGiftiXml(absl::string_view(bytes.data(), bytes.size()), p));
  RETURN_IF_ERROR(DecodeArray(p.points, kPoints, name));
  RETURN_IF_ERROR(DecodeArray(p.triangles, kTriangles, name));
  return ToSoup(p.points, p.triangles, name);
}

absl::StatusOr<TriangleSoup> ReadGiftiSurface(const std::string& path, std::string_view name,
                                              uint64_t max_decoded_bytes) {
  std::error_code ec;
  const uint64_t size = std::filesystem::file_size(path, ec);
  if (ec) {
    return absl::InvalidArgumentError(absl::StrFormat("%s: cannot read (%s)", name, ec.message()));
  }
  if (size > kMaxGiftiFileBytes) {
    return absl::ResourceExhaustedError(absl::StrFormat(
        "%s: %u bytes, more than the %u a GIFTI file may have", name, size, kMaxGiftiFileBytes));
  }
  std::ifstream in(path, std::ios::binary);
  std::string bytes(size, '\0');
  if (!in.read(bytes.data(), static_cast<std::streamsize>(size))) {
    return absl::InvalidArgumentError(absl::StrFormat("%s: cannot read", name));
  }
  return ReadGiftiSurfaceFromMemory(bytes, name, max_decoded_bytes);
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
