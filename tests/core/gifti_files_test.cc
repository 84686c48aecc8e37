// GIFTI surfaces and metrics: surfaces written by libgiftiio in every
// encoding, order and coordinate type read back bit for bit, from a path and
// from memory, big-endian too; malformed, truncated, misshapen and
// external-data files give errors naming the file, and nothing on stderr;
// the shapes that crashed libgiftiio are refused by the schema check, and
// declarations beyond a budget or beyond what their data can hold before
// anything is decoded; a field written as .func.gii reads back as float32
// with +inf kept. Also the temporary files of mesh uploads, which a daemon
// killed mid-read leaves behind for the next one to remove.
#include "core/mesh/gifti_files.h"

// C without extern "C" guards of its own.
extern "C" {
#include <gifti_io.h>
}
#include <sys/wait.h>
#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <numbers>
#include <regex>
#include <sstream>
#include <vector>

#include "absl/strings/escaping.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_replace.h"
#include "core/mesh/mesh_io.h"
#include "core/query/result_files.h"
#include "tests/core/test_util.h"

namespace geodesic {
namespace {

using ::testing::HasSubstr;
using testing::ReadBytes;
using testing::TempDir;
using testing::WriteBytes;

// An open box (a cube without its top): 8 vertices, 10 triangles, with
// coordinates no short decimal holds, so that any rounding on the way shows.
struct SmallSurface {
  std::vector<float> xyz;      // row-major N x 3
  std::vector<int32_t> faces;  // row-major M x 3
};

SmallSurface OpenBox() {
  SmallSurface s;
  for (int k = 0; k < 8; ++k) {
    s.xyz.push_back(static_cast<float>((k & 1) / 3.0 + 0.1 * k));
    s.xyz.push_back(static_cast<float>(((k >> 1) & 1) * std::sqrt(2.0) - 1e-7 * k));
    s.xyz.push_back(static_cast<float>(((k >> 2) & 1) * std::numbers::pi + 1e5));
  }
  s.faces = {0, 2, 1, 1, 2, 3, 0, 1, 5, 0, 5, 4, 1, 3, 7,
             1, 7, 5, 3, 2, 6, 3, 6, 7, 2, 0, 4, 2, 4, 6};
  return s;
}

struct Layout {
  int encoding;
  bool column_major;
  bool float64;
  int triangle_type = NIFTI_TYPE_INT32;  // int64 as nibabel writes numpy's default
};

// `rows` x 3 values of `data` (row-major) stored into `da`'s own buffer in its
// indexing order, as type T.
template <typename T, typename S>
void Fill(giiDataArray* da, const std::vector<S>& data, int rows) {
  da->data = std::malloc(data.size() * sizeof(T));
  T* out = static_cast<T*>(da->data);
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < 3; ++c) {
      const int i = da->ind_ord == GIFTI_IND_ORD_COL_MAJOR ? c * rows + r : r * 3 + c;
      out[i] = static_cast<T>(data[r * 3 + c]);
    }
  }
}

void SetArray(giiDataArray* da, int intent, int datatype, int rows, const Layout& layout) {
  da->intent = intent;
  da->datatype = datatype;
  da->num_dim = 2;
  da->dims[0] = rows;
  da->dims[1] = 3;
  da->encoding = layout.encoding;
  da->endian = gifti_get_this_endian();
  da->ind_ord = layout.column_major ? GIFTI_IND_ORD_COL_MAJOR : GIFTI_IND_ORD_ROW_MAJOR;
  int swapsize = 0;
  gifti_datatype_sizes(datatype, &da->nbyper, &swapsize);
  da->nvals = int64_t{3} * rows;
}

// ASCII by hand: libgiftiio writes ASCII floats with six decimals, which
// would test its writer's rounding rather than the reader. Nine significant
// digits hold any float32.
void WriteAsciiSurface(const std::string& path, const SmallSurface& s, bool column_major,
                       int triangle_type) {
  const size_t nv = s.xyz.size() / 3, nf = s.faces.size() / 3;
  auto array = [&](const char* intent, const char* type, size_t rows, auto&& value) {
    std::string text = absl::StrFormat(
        "<DataArray Intent=\"%s\" DataType=\"%s\" ArrayIndexingOrder=\"%s\" "
        "Dimensionality=\"2\" Dim0=\"%u\" Dim1=\"3\" Encoding=\"ASCII\" "
        "Endian=\"LittleEndian\" ExternalFileName=\"\" ExternalFileOffset=\"\">\n<Data>",
        intent, type, column_major ? "ColumnMajorOrder" : "RowMajorOrder", rows);
    for (size_t i = 0; i < 3 * rows; ++i) {
      const size_t r = column_major ? i % rows : i / 3, c = column_major ? i / rows : i % 3;
      absl::StrAppend(&text, value(r * 3 + c), i + 1 < 3 * rows ? " " : "");
    }
    return text + "</Data>\n</DataArray>\n";
  };
  WriteBytes(path,
             "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
             "<GIFTI Version=\"1.0\" NumberOfDataArrays=\"2\">\n" +
                 array("NIFTI_INTENT_POINTSET", "NIFTI_TYPE_FLOAT32", nv,
                       [&](size_t i) { return absl::StrFormat("%.9g", s.xyz[i]); }) +
                 array("NIFTI_INTENT_TRIANGLE", gifti_datatype2str(triangle_type), nf,
                       [&](size_t i) { return absl::StrCat(s.faces[i]); }) +
                 "</GIFTI>\n");
}

// Writes `s` as a GIFTI surface with libgiftiio itself (ASCII by hand, as
// above); `with_triangles` false leaves the triangle array out.
void WriteSurface(const std::string& path, const SmallSurface& s, const Layout& layout,
                  bool with_triangles = true) {
  if (layout.encoding == GIFTI_ENCODING_ASCII && !layout.float64 && with_triangles) {
    WriteAsciiSurface(path, s, layout.column_major, layout.triangle_type);
    return;
  }
  gifti_set_verb(0);
  const int num_da = with_triangles ? 2 : 1;
  const int dims[2] = {static_cast<int>(s.xyz.size() / 3), 3};
  gifti_image* image = gifti_create_image(num_da, NIFTI_INTENT_POINTSET, NIFTI_TYPE_FLOAT32, 2,
                                          dims, /*alloc_data=*/0);
  ASSERT_NE(image, nullptr);
  const int nv = dims[0], nf = static_cast<int>(s.faces.size() / 3);
  giiDataArray* points = image->darray[0];
  SetArray(points, NIFTI_INTENT_POINTSET, layout.float64 ? NIFTI_TYPE_FLOAT64 : NIFTI_TYPE_FLOAT32,
           nv, layout);
  if (layout.float64) {
    Fill<double>(points, s.xyz, nv);
  } else {
    Fill<float>(points, s.xyz, nv);
  }
  if (with_triangles) {
    giiDataArray* triangles = image->darray[1];
    SetArray(triangles, NIFTI_INTENT_TRIANGLE, layout.triangle_type, nf, layout);
    switch (layout.triangle_type) {
      case NIFTI_TYPE_INT64:
        Fill<int64_t>(triangles, s.faces, nf);
        break;
      case NIFTI_TYPE_UINT32:
        Fill<uint32_t>(triangles, s.faces, nf);
        break;
      default:
        Fill<int32_t>(triangles, s.faces, nf);
    }
  }
  ASSERT_EQ(gifti_write_image(image, path.c_str(), 1), 0) << path;
  gifti_free_image(image);
}

void ExpectSameSurface(const TriangleSoup& soup, const SmallSurface& s) {
  ASSERT_EQ(soup.positions.size() * 3, s.xyz.size());
  for (size_t v = 0; v < soup.positions.size(); ++v) {
    const Vec3& p = soup.positions[v];
    // Bit for bit: the double holds the file's float exactly.
    EXPECT_EQ(p.x, static_cast<double>(s.xyz[3 * v])) << "vertex " << v;
    EXPECT_EQ(p.y, static_cast<double>(s.xyz[3 * v + 1])) << "vertex " << v;
    EXPECT_EQ(p.z, static_cast<double>(s.xyz[3 * v + 2])) << "vertex " << v;
  }
  ASSERT_EQ(soup.triangles.size() * 3, s.faces.size());
  for (size_t f = 0; f < soup.triangles.size(); ++f) {
    for (int k = 0; k < 3; ++k) {
      EXPECT_EQ(soup.triangles[f][k], static_cast<VertexId>(s.faces[3 * f + k])) << "face " << f;
    }
  }
}

class GiftiLayoutTest : public ::testing::TestWithParam<Layout> {};

TEST_P(GiftiLayoutTest, ReadsBackBitForBitFromPathAndMemory) {
  TempDir dir;
  const std::string path = dir.File("box.surf.gii");
  const SmallSurface box = OpenBox();
  WriteSurface(path, box, GetParam());
  ASSERT_EQ(MeshFormatOfPath(path), "gii");

  MeshDiagnostics d;
  auto soup = ReadTriangleSoup(path, &d);
  ASSERT_OK(soup);
  ExpectSameSurface(*soup, box);
  EXPECT_EQ(d.format, "gii");

  auto uploaded = ReadTriangleSoupFromMemory(ReadBytes(path), "gii", "upload.surf.gii");
  ASSERT_OK(uploaded);
  ExpectSameSurface(*uploaded, box);

  auto mesh = LoadMesh(path);
  ASSERT_OK(mesh);
  EXPECT_EQ(mesh->num_vertices(), 8u);
  EXPECT_EQ(mesh->num_faces(), 10u);
}

std::string LayoutName(const ::testing::TestParamInfo<Layout>& info) {
  const char* names[] = {"Undef", "Ascii", "Base64", "GzipBase64", "External"};
  const char* triangles = info.param.triangle_type == NIFTI_TYPE_INT64    ? "Int64"
                          : info.param.triangle_type == NIFTI_TYPE_UINT32 ? "Uint32"
                                                                          : "";
  return absl::StrFormat("%s%s%s%s", names[info.param.encoding],
                         info.param.column_major ? "ColumnMajor" : "RowMajor",
                         info.param.float64 ? "Float64" : "Float32", triangles);
}

INSTANTIATE_TEST_SUITE_P(
    Encodings, GiftiLayoutTest,
    ::testing::Values(
        Layout{GIFTI_ENCODING_ASCII, false, false}, Layout{GIFTI_ENCODING_B64BIN, false, false},
        Layout{GIFTI_ENCODING_B64GZ, false, false}, Layout{GIFTI_ENCODING_B64GZ, true, false},
        Layout{GIFTI_ENCODING_B64BIN, true, false}, Layout{GIFTI_ENCODING_ASCII, true, false},
        Layout{GIFTI_ENCODING_B64GZ, false, true}, Layout{GIFTI_ENCODING_B64BIN, true, true},
        Layout{GIFTI_ENCODING_B64GZ, false, true, NIFTI_TYPE_INT64},
        Layout{GIFTI_ENCODING_ASCII, false, false, NIFTI_TYPE_INT64},
        Layout{GIFTI_ENCODING_B64BIN, true, false, NIFTI_TYPE_UINT32}),
    LayoutName);

// A hand-written surface, ASCII: the triangle array's attributes and values
// are `triangle_attributes` and `triangle_text`.
std::string AsciiSurface(const std::string& point_text, const std::string& triangle_attributes,
                         const std::string& triangle_text) {
  return absl::StrFormat(
      "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
      "<GIFTI Version=\"1.0\" NumberOfDataArrays=\"2\">\n"
      "<DataArray Intent=\"NIFTI_INTENT_POINTSET\" DataType=\"NIFTI_TYPE_FLOAT32\" "
      "ArrayIndexingOrder=\"RowMajorOrder\" Dimensionality=\"2\" Dim0=\"3\" Dim1=\"3\" "
      "Encoding=\"ASCII\" Endian=\"LittleEndian\" ExternalFileName=\"\" ExternalFileOffset=\"\">\n"
      "<Data>%s</Data></DataArray>\n"
      "<DataArray Intent=\"NIFTI_INTENT_TRIANGLE\" DataType=\"NIFTI_TYPE_INT32\" "
      "ArrayIndexingOrder=\"RowMajorOrder\" %s>\n"
      "<Data>%s</Data></DataArray>\n"
      "</GIFTI>\n",
      point_text, triangle_attributes, triangle_text);
}

const char kPoints[] = "0 0 0 1 0 0 0 1 0";

// AsciiSurface with one triangle as binary data (`base64`) in `encoding`.
std::string Binary(const std::string& endian, const std::string& encoding,
                   const std::string& base64) {
  return AsciiSurface(kPoints,
                      absl::StrFormat("Dimensionality=\"2\" Dim0=\"1\" Dim1=\"3\" "
                                      "Encoding=\"%s\"%s",
                                      encoding, endian),
                      base64);
}
const char kTriangleAttributes[] =
    "Dimensionality=\"2\" Dim0=\"1\" Dim1=\"3\" Encoding=\"ASCII\" ExternalFileName=\"\" "
    "ExternalFileOffset=\"\"";

TEST(GiftiErrors, HandWrittenAsciiSurfaceReads) {
  auto soup = ReadTriangleSoupFromMemory(AsciiSurface(kPoints, kTriangleAttributes, "0 1 2"), "gii",
                                         "tri.surf.gii");
  ASSERT_OK(soup);
  EXPECT_EQ(soup->positions.size(), 3u);
  EXPECT_EQ(soup->triangles.size(), 1u);
}

// Each case: bytes, and what the message must say besides the file's name.
struct BadFile {
  const char* label;
  std::string bytes;
  const char* says;
};

const char kLittle[] = " Endian=\"LittleEndian\"";

std::vector<BadFile> BadFiles() {
  TempDir dir;
  const std::string good = dir.File("good.surf.gii");
  WriteSurface(good, OpenBox(), {GIFTI_ENCODING_B64GZ, false, false});
  const std::string bytes = ReadBytes(good);
  std::string garbage(4096, '\0');
  uint32_t x = 12345;
  for (char& c : garbage) c = static_cast<char>((x = x * 1103515245u + 12345u) >> 16);
  const std::string no_triangles = dir.File("points.surf.gii");
  WriteSurface(no_triangles, OpenBox(), {GIFTI_ENCODING_B64BIN, false, false}, false);
  return {
      {"truncated", bytes.substr(0, bytes.size() / 2), "not a readable GIFTI file"},
      {"truncated in the data", bytes.substr(0, bytes.rfind("</Data>") - 8),
       "not a readable GIFTI file"},
      {"garbage", garbage, "not a readable GIFTI file"},
      {"xml but not gifti", "<?xml version=\"1.0\"?>\n<svg></svg>\n", "not a GIFTI file"},
      {"no triangle array", ReadBytes(no_triangles), "no triangle array"},
      {"N x 2 triangles",
       AsciiSurface(kPoints, "Dimensionality=\"2\" Dim0=\"1\" Dim1=\"2\" Encoding=\"ASCII\"",
                    "0 1"),
       "not N x 3"},
      {"external data",
       AsciiSurface(kPoints,
                    "Dimensionality=\"2\" Dim0=\"1\" Dim1=\"3\" Encoding=\"ExternalFileBinary\" "
                    "ExternalFileName=\"/etc/passwd\" ExternalFileOffset=\"0\"",
                    ""),
       "external file ('/etc/passwd')"},
      {"index out of range", AsciiSurface(kPoints, kTriangleAttributes, "0 1 3"),
       "refers to vertex 3"},
      {"negative index", AsciiSurface(kPoints, kTriangleAttributes, "0 -1 2"),
       "refers to vertex -1"},
      {"int64 index past any vertex id",
       absl::StrReplaceAll(AsciiSurface(kPoints, kTriangleAttributes, "0 1 4294967298"),
                           {{"NIFTI_TYPE_INT32", "NIFTI_TYPE_INT64"}}),
       "refers to vertex 4294967298"},
      {"int16 triangles",
       absl::StrReplaceAll(AsciiSurface(kPoints, kTriangleAttributes, "0 1 2"),
                           {{"NIFTI_TYPE_INT32", "NIFTI_TYPE_INT16"}}),
       "holds NIFTI_TYPE_INT16, not int32, int64 or uint32"},
      {"nan coordinate", AsciiSurface("0 0 0 1 nan 0 0 1 0", kTriangleAttributes, "0 1 2"),
       "non-finite coordinate"},
      {"ASCII data short of Dim0", AsciiSurface(kPoints, kTriangleAttributes, "0 1"),
       "declares 3 values but its data holds 2"},
      {"ASCII data beyond Dim0", AsciiSurface(kPoints, kTriangleAttributes, "0 1 2 0"),
       "declares 3 values but its data holds 4"},
      {"ASCII word", AsciiSurface(kPoints, kTriangleAttributes, "0 one 2"), "'one', not a number"},
      {"binary data short of Dim0", Binary(kLittle, "Base64Binary", "AAAAAAEAAAA="),
       "declares 3 values but its data holds 2"},
      {"gzip data short of Dim0", Binary(kLittle, "GZipBase64Binary", "eJxjYGBgYARiAAAMAAI="),
       "declares 3 values but its data holds 2"},
      {"binary data beyond Dim0", Binary(kLittle, "Base64Binary", "AAAAAAEAAAACAAAAAwAAAA=="),
       "declares 3 values but its data holds 4"},
      {"gzip data beyond Dim0", Binary(kLittle, "GZipBase64Binary", "eJxjYGBgYARiJiBmBmIAADgABw=="),
       "declares 3 values but its data holds more"},
      {"not base64", Binary(kLittle, "Base64Binary", "!!!!"), "not base64"},
      {"unpadded base64", Binary(kLittle, "Base64Binary", "AAAAAAEAAAACAAA"), "not base64"},
      {"base64 but not zlib", Binary(kLittle, "GZipBase64Binary", "AAAAAAEAAAA="), "not zlib"},
      {"no Endian", Binary("", "Base64Binary", "AAAAAAEAAAACAAAA"), "Endian is missing"},
      {"huge declared size",
       AsciiSurface(kPoints,
                    "Dimensionality=\"2\" Dim0=\"700000000\" Dim1=\"3\" Encoding=\"ASCII\"",
                    "0 1 2"),
       "more than its"},
      {"dimensions beyond 32 bits",
       AsciiSurface(kPoints,
                    "Dimensionality=\"2\" Dim0=\"2000000000\" Dim1=\"3\" Encoding=\"ASCII\"",
                    "0 1 2"),
       "more than 2^31 - 1 values"},
      {"negative Dim0",
       AsciiSurface(kPoints, "Dimensionality=\"2\" Dim0=\"-1\" Dim1=\"3\" Encoding=\"ASCII\"",
                    "0 1 2"),
       "Dim0 '-1' is not a positive integer"},
      {"Dimensionality 7",
       AsciiSurface(kPoints, "Dimensionality=\"7\" Dim0=\"1\" Dim1=\"3\" Encoding=\"ASCII\"",
                    "0 1 2"),
       "Dimensionality '7' is not 1 to 6"},
      {"unknown encoding",
       AsciiSurface(kPoints, "Dimensionality=\"2\" Dim0=\"1\" Dim1=\"3\" Encoding=\"Hex\"",
                    "0 1 2"),
       "Encoding 'Hex'"},
      {"miscounted arrays",
       std::regex_replace(AsciiSurface(kPoints, kTriangleAttributes, "0 1 2"),
                          std::regex("NumberOfDataArrays=\"2\""), "NumberOfDataArrays=\"3\""),
       "NumberOfDataArrays says 3"},
  };
}

TEST(GiftiErrors, MalformedFilesAreRefusedNamingTheFile) {
  TempDir dir;
  const std::vector<BadFile> bad_files = BadFiles();
  // The daemon's stderr is its log: no reader may complain there.
  ::testing::internal::CaptureStderr();
  for (const BadFile& bad : bad_files) {
    SCOPED_TRACE(bad.label);
    const std::string path = dir.File("bad.surf.gii");
    WriteBytes(path, bad.bytes);
    auto soup = ReadTriangleSoup(path);
    ASSERT_FALSE(soup.ok());
    EXPECT_EQ(soup.status().code(), absl::StatusCode::kInvalidArgument) << soup.status();
    EXPECT_THAT(soup.status().message(), HasSubstr(path));
    EXPECT_THAT(soup.status().message(), HasSubstr(bad.says));
    auto uploaded = ReadTriangleSoupFromMemory(bad.bytes, "gii", "sent.surf.gii");
    ASSERT_FALSE(uploaded.ok());
    EXPECT_THAT(uploaded.status().message(), HasSubstr("sent.surf.gii"));
    EXPECT_THAT(uploaded.status().message(), HasSubstr(bad.says));
  }
  EXPECT_EQ(::testing::internal::GetCapturedStderr(), "");
}

// Both entry points, the path (through the mesh reader) and the upload,
// refuse `bytes` with `code`, naming the file and saying `says`.
void ExpectRefused(const std::string& bytes, const std::string& says,
                   absl::StatusCode code = absl::StatusCode::kInvalidArgument,
                   uint64_t max_decoded_bytes = 0) {
  TempDir dir;
  const std::string path = dir.File("bad.surf.gii");
  WriteBytes(path, bytes);
  auto soup = max_decoded_bytes == 0 ? ReadTriangleSoup(path)
                                     : ReadGiftiSurface(path, path, max_decoded_bytes);
  ASSERT_FALSE(soup.ok());
  EXPECT_EQ(soup.status().code(), code) << soup.status();
  EXPECT_THAT(soup.status().message(), HasSubstr(path));
  EXPECT_THAT(soup.status().message(), HasSubstr(says));
  auto uploaded =
      ReadTriangleSoupFromMemory(bytes, "gii", "sent.surf.gii", nullptr, max_decoded_bytes);
  ASSERT_FALSE(uploaded.ok());
  EXPECT_EQ(uploaded.status().code(), code) << uploaded.status();
  EXPECT_THAT(uploaded.status().message(), HasSubstr("sent.surf.gii"));
  EXPECT_THAT(uploaded.status().message(), HasSubstr(says));
}

std::string Repeat(const std::string& text, int times) {
  std::string out;
  for (int k = 0; k < times; ++k) out += text;
  return out;
}

// Each shape crashed libgiftiio (a NULL dereference in its XML callbacks);
// each is now an element the schema has no place for, named with its parent.
TEST(GiftiSchema, ShapesThatCrashedLibgiftiioAreRefused) {
  const std::string empty = "<GIFTI NumberOfDataArrays=\"0\">";
  const std::string tiny = empty + "<Data/></GIFTI>";
  ASSERT_EQ(tiny.size(), 45u);
  const struct {
    const char* label;
    std::string bytes;
    std::string says;
  } shapes[] = {
      {"Data outside DataArray (the 45-byte file)", tiny,
       "line 1: a <Data> element inside <GIFTI>, where GIFTI allows only <MetaData>, "
       "<LabelTable>, <DataArray>"},
      {"MD outside MetaData", empty + "\n<MD><Name>a</Name></MD></GIFTI>",
       "line 2: a <MD> element inside <GIFTI>"},
      {"MD inside MD", empty + "<MetaData><MD><MD/></MD></MetaData></GIFTI>",
       "a <MD> element inside <MD>, where GIFTI allows only <Name>, <Value>"},
      {"MetaData inside a Label",
       empty + "<LabelTable><Label Key=\"0\"><MetaData/></Label></LabelTable></GIFTI>",
       "a <MetaData> element inside <Label>, which holds only text"},
      {"Value nested 100,000 deep",
       empty + "<MetaData><MD>" + Repeat("<Value>", 100000) + Repeat("</Value>", 100000) +
           "</MD></MetaData></GIFTI>",
       "a <Value> element inside <Value>, which holds only text"},
      {"unknown element nested 9 deep",
       empty + "<MetaData><MD>" + Repeat("<Foo>", 9) + Repeat("</Foo>", 9) +
           "</MD></MetaData></GIFTI>",
       "an unknown element <Foo> inside <MD>"},
      {"GIFTI inside GIFTI", empty + "<GIFTI/></GIFTI>", "a <GIFTI> element inside <GIFTI>"},
      {"a second Data",
       empty + "<DataArray Encoding=\"ASCII\" Dimensionality=\"1\" Dim0=\"1\"><Data>1</Data>"
               "<Data>2</Data></DataArray></GIFTI>",
       "a second <Data> element"},
      {"an entity", "<!DOCTYPE GIFTI [<!ENTITY a \"aaaa\">]>" + empty + "</GIFTI>",
       "an entity declaration (a)"},
  };
  for (const auto& shape : shapes) {
    SCOPED_TRACE(shape.label);
    ExpectRefused(shape.bytes, shape.says);
  }
}

// The whole file is one expat call, so the attribute is scanned once, then
// refused by its length.
TEST(GiftiSchema, A16MegabyteAttributeIsRefusedByName) {
  const std::string bytes =
      "<GIFTI NumberOfDataArrays=\"0\" Junk=\"" + std::string(16 << 20, 'a') + "\"></GIFTI>";
  ExpectRefused(bytes, "attribute Junk is 16777216 characters long");
}

// A surface as nibabel and Workbench write them, besides the two arrays:
// metadata, a label table, a transform, and another array whose data is not
// even decoded.
TEST(GiftiSchema, MetadataLabelsTransformsAndOtherArraysAreSkipped) {
  const std::string shape =
      "<DataArray Intent=\"NIFTI_INTENT_SHAPE\" DataType=\"NIFTI_TYPE_FLOAT32\" "
      "ArrayIndexingOrder=\"RowMajorOrder\" Dimensionality=\"1\" Dim0=\"3\" "
      "Encoding=\"GZipBase64Binary\" Endian=\"LittleEndian\" ExternalFileName=\"\">\n"
      "<MetaData><MD><Name>Name</Name><Value><![CDATA[thickness]]></Value></MD></MetaData>\n"
      "<CoordinateSystemTransformMatrix><DataSpace>NIFTI_XFORM_UNKNOWN</DataSpace>"
      "<TransformedSpace>NIFTI_XFORM_UNKNOWN</TransformedSpace>"
      "<MatrixData>1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1</MatrixData>"
      "</CoordinateSystemTransformMatrix>\n<Data>not decoded</Data></DataArray>\n";
  std::string surface = AsciiSurface(kPoints, kTriangleAttributes, "0 1 2");
  surface = absl::StrReplaceAll(
      surface,
      {{"NumberOfDataArrays=\"2\">\n",
        "NumberOfDataArrays=\"3\">\n<MetaData><MD><Name>AnatomicalStructurePrimary</Name>"
        "<Value>CortexLeft</Value></MD></MetaData>\n<LabelTable><Label Key=\"0\" Red=\"1\" "
        "Green=\"1\" Blue=\"1\" Alpha=\"0\">Unknown</Label></LabelTable>\n" +
            shape}});
  auto soup = ReadTriangleSoupFromMemory(surface, "gii", "full.surf.gii");
  ASSERT_OK(soup);
  EXPECT_EQ(soup->positions.size(), 3u);
  EXPECT_EQ(soup->triangles.size(), 1u);
}

// zlib's compression of `bytes` zero bytes, made a block at a time.
std::string CompressedZeros(uint64_t bytes) {
  z_stream z{};
  EXPECT_EQ(deflateInit(&z, Z_BEST_COMPRESSION), Z_OK);
  const std::string zeros(1 << 16, '\0');
  std::string out, block(1 << 16, '\0');
  for (uint64_t left = bytes;;) {
    const uint64_t n = std::min<uint64_t>(left, zeros.size());
    z.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(zeros.data()));
    z.avail_in = static_cast<uInt>(n);
    left -= n;
    const int flush = left == 0 ? Z_FINISH : Z_NO_FLUSH;
    do {
      z.next_out = reinterpret_cast<Bytef*>(block.data());
      z.avail_out = static_cast<uInt>(block.size());
      deflate(&z, flush);
      out.append(block.data(), block.size() - z.avail_out);
    } while (z.avail_out == 0);
    if (flush == Z_FINISH) break;
  }
  deflateEnd(&z);
  return out;
}

// A surface of kPoints and `rows` triangles whose data is `zlib`.
std::string GzipTriangles(int64_t rows, const std::string& zlib) {
  return AsciiSurface(kPoints,
                      absl::StrFormat("Dimensionality=\"2\" Dim0=\"%d\" Dim1=\"3\" "
                                      "Encoding=\"GZipBase64Binary\" Endian=\"LittleEndian\"",
                                      rows),
                      absl::Base64Escape(zlib));
}

constexpr uint64_t k64MiB = 64 << 20;

// 100 million triangles (1.2 GB) declared over a zlib stream of a dozen
// bytes: over a budget, refused by it as the array opens; without one,
// refused as more than those bytes can hold; either way before any
// allocation.
TEST(GiftiBudget, OverdeclaredGzipIsRefusedBeforeDecoding) {
  const std::string zlib = CompressedZeros(12);
  ASSERT_LT(zlib.size(), 30u);
  const std::string bytes = GzipTriangles(100'000'000, zlib);
  ExpectRefused(bytes, "the triangle array (DataArray 1) declares 1200000000 bytes",
                absl::StatusCode::kResourceExhausted, k64MiB);
  ExpectRefused(bytes, "more than the limit of 67108864 bytes",
                absl::StatusCode::kResourceExhausted, k64MiB);
  ExpectRefused(bytes, "declares 300000000 values (1200000000 bytes), more than its");
}

// A genuine bomb: 256 MiB of zero indices, honestly declared, in 260 KB.
// Over a 64 MiB budget it is refused as the array opens. Without one it
// would be decoded, so its pointset is made a shape array: the file is then
// refused for its shape before decoding (the sanitizer lanes run these
// tests: no half-gigabyte here). A 16 MiB one under the budget is decoded.
TEST(GiftiBudget, HonestZlibBombIsRefusedOverTheBudgetOnly) {
  const int64_t rows = (256 << 20) / 12;
  const std::string triangles_only =
      absl::StrReplaceAll(GzipTriangles(rows, CompressedZeros(rows * 12)),
                          {{"NIFTI_INTENT_POINTSET", "NIFTI_INTENT_SHAPE"}});
  ASSERT_LT(triangles_only.size(), 1u << 20);
  ExpectRefused(triangles_only, "declares 268435452 bytes of data",
                absl::StatusCode::kResourceExhausted, k64MiB);
  ExpectRefused(triangles_only, "no pointset array");

  const int64_t fits = (16 << 20) / 12;
  auto soup = ReadGiftiSurfaceFromMemory(GzipTriangles(fits, CompressedZeros(fits * 12)),
                                         "bomb.surf.gii", k64MiB);
  ASSERT_OK(soup);
  EXPECT_EQ(soup->triangles.size(), static_cast<size_t>(fits));
  EXPECT_EQ(soup->triangles.back()[2], 0u);
}

// `values` as `T`s in big-endian byte order, base64.
template <typename T, typename S>
std::string BigEndianBase64(const std::vector<S>& values, bool gzip) {
  std::string bytes;
  for (S value : values) {
    const T t = static_cast<T>(value);
    char raw[sizeof(T)];
    std::memcpy(raw, &t, sizeof(T));
    std::reverse(raw, raw + sizeof(T));
    bytes.append(raw, sizeof(T));
  }
  if (gzip) {
    uLongf size = compressBound(bytes.size());
    std::string packed(size, '\0');
    EXPECT_EQ(compress2(reinterpret_cast<Bytef*>(packed.data()), &size,
                        reinterpret_cast<const Bytef*>(bytes.data()), bytes.size(), 9),
              Z_OK);
    bytes = packed.substr(0, size);
  }
  return absl::Base64Escape(bytes);
}

TEST(GiftiEndian, BigEndianArraysReadBitForBit) {
  const SmallSurface box = OpenBox();
  for (const bool gzip : {false, true}) {
    SCOPED_TRACE(gzip ? "GZipBase64Binary" : "Base64Binary");
    const char* encoding = gzip ? "GZipBase64Binary" : "Base64Binary";
    auto array = [&](const char* intent, const char* type, size_t rows, const std::string& data) {
      return absl::StrFormat(
          "<DataArray Intent=\"%s\" DataType=\"%s\" ArrayIndexingOrder=\"RowMajorOrder\" "
          "Dimensionality=\"2\" Dim0=\"%u\" Dim1=\"3\" Encoding=\"%s\" Endian=\"BigEndian\">"
          "<Data>%s</Data></DataArray>\n",
          intent, type, rows, encoding, data);
    };
    const std::string bytes =
        "<GIFTI NumberOfDataArrays=\"2\">\n" +
        array("NIFTI_INTENT_POINTSET", "NIFTI_TYPE_FLOAT32", box.xyz.size() / 3,
              BigEndianBase64<float>(box.xyz, gzip)) +
        array("NIFTI_INTENT_TRIANGLE", "NIFTI_TYPE_INT32", box.faces.size() / 3,
              BigEndianBase64<int32_t>(box.faces, gzip)) +
        "</GIFTI>\n";
    auto soup = ReadGiftiSurfaceFromMemory(bytes, "big.surf.gii");
    ASSERT_OK(soup);
    ExpectSameSurface(*soup, box);
  }
}

// A mesh upload read through a temporary file (OpenMesh's formats) leaves
// geodesic-mesh-<pid>-*; a daemon killed mid-read leaves it behind, and the
// next one removes it. Run in a temporary directory of its own (TMPDIR).
TEST(MeshIoTemporaryFiles, StaleFilesOfDeadProcessesAreRemoved) {
  TempDir dir;
  const char* saved = std::getenv("TMPDIR");
  const std::string saved_tmpdir = saved ? saved : "";
  ASSERT_EQ(setenv("TMPDIR", dir.path().c_str(), 1), 0);
  const pid_t child = fork();
  if (child == 0) _exit(0);
  ASSERT_GT(child, 0);
  ASSERT_EQ(waitpid(child, nullptr, 0), child);  // a pid no process has now
  const auto two_hours_ago = std::filesystem::file_time_type::clock::now() - std::chrono::hours(2);
  const std::string dead = absl::StrFormat("geodesic-mesh-%d-Ab12Cd.obj", child);
  const std::string live = absl::StrFormat("geodesic-mesh-%d-Ab12Cd.obj", getpid());
  const std::string old_style = "geodesic-mesh-Xy34Zw.off";
  const std::string recent_old_style = "geodesic-mesh-Qr56St.off";
  const std::string other = "not-a-mesh-file.obj";
  for (const std::string& name : {dead, live, old_style, recent_old_style, other}) {
    WriteBytes(dir.File(name), "x");
  }
  std::filesystem::last_write_time(dir.File(old_style), two_hours_ago);
  std::filesystem::last_write_time(dir.File(live), two_hours_ago);
  std::filesystem::last_write_time(dir.File(other), two_hours_ago);
  RemoveStaleTemporaryMeshFiles();
  EXPECT_FALSE(std::filesystem::exists(dir.File(dead)));
  EXPECT_FALSE(std::filesystem::exists(dir.File(old_style)));
  EXPECT_TRUE(std::filesystem::exists(dir.File(live)));
  EXPECT_TRUE(std::filesystem::exists(dir.File(recent_old_style)));
  EXPECT_TRUE(std::filesystem::exists(dir.File(other)));
  // An upload leaves nothing behind in any format, and a GIFTI one writes
  // nothing at all.
  std::filesystem::remove(dir.File(live));
  std::filesystem::remove(dir.File(recent_old_style));
  std::filesystem::remove(dir.File(other));
  EXPECT_OK(ReadTriangleSoupFromMemory("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", "off", "t"));
  EXPECT_OK(ReadTriangleSoupFromMemory(AsciiSurface(kPoints, kTriangleAttributes, "0 1 2"), "gii",
                                       "t.surf.gii"));
  EXPECT_TRUE(std::filesystem::is_empty(dir.path()));
  if (saved) {
    setenv("TMPDIR", saved_tmpdir.c_str(), 1);
  } else {
    unsetenv("TMPDIR");
  }
}

TEST(GiftiErrors, EmptyFileAndUnknownExtension) {
  TempDir dir;
  WriteBytes(dir.File("empty.surf.gii"), "");
  EXPECT_THAT(ReadTriangleSoup(dir.File("empty.surf.gii")).status().message(), HasSubstr("empty"));
  EXPECT_TRUE(IsMeshFormat("gii"));
  EXPECT_THAT(MeshFormatList(), HasSubstr("gii"));
}

TEST(GiftiMetric, FieldReadsBackAsFloat32WithInf) {
  TempDir dir;
  const std::string path = dir.File("d.func.gii");
  const double inf = std::numeric_limits<double>::infinity();
  const std::vector<double> field = {0.0, 1.0 / 3.0, 2.5, inf, 1e-3, 12345.678901234};
  ASSERT_OK(WriteField(path, field));

  gifti_set_verb(0);
  gifti_image* image = gifti_read_image(path.c_str(), 1);
  ASSERT_NE(image, nullptr);
  ASSERT_EQ(image->numDA, 1);
  const giiDataArray* da = image->darray[0];
  EXPECT_EQ(da->intent, NIFTI_INTENT_SHAPE);
  EXPECT_EQ(da->datatype, NIFTI_TYPE_FLOAT32);
  EXPECT_EQ(da->encoding, GIFTI_ENCODING_B64GZ);
  EXPECT_EQ(da->num_dim, 1);
  ASSERT_EQ(da->nvals, static_cast<int64_t>(field.size()));
  const float* got = static_cast<const float*>(da->data);
  for (size_t i = 0; i < field.size(); ++i) {
    EXPECT_EQ(got[i], static_cast<float>(field[i])) << "vertex " << i;
  }
  EXPECT_TRUE(std::isinf(got[3]) && got[3] > 0);
  gifti_free_image(image);
}

TEST(GiftiMetric, ExtensionIsFuncGii) {
  EXPECT_OK(CheckFieldPath("out/D.FUNC.GII", false));
  EXPECT_THAT(CheckFieldPath("d.gii", false).message(), HasSubstr(".func.gii"));
  EXPECT_THAT(CheckFieldPath("d.surf.gii", false).message(), HasSubstr("cannot write"));
  EXPECT_FALSE(CheckFieldPath("dir.func.gii/", false).ok());
}

}  // namespace
}  // namespace geodesic
