// Result files in every format, read back byte by byte.
#include "core/query/result_files.h"

#include <cstring>
#include <fstream>
#include <limits>
#include <sstream>

#include "absl/strings/str_split.h"
#include "tests/core/test_util.h"

namespace geodesic {
namespace {

using ::testing::HasSubstr;
using testing::ReadBytes;
using testing::TempDir;

using testing::kInf;

std::vector<std::string> Lines(const std::string& text) {
  return absl::StrSplit(text, '\n', absl::SkipEmpty());
}

TEST(ResultFilesTest, FieldAsRawFloat64) {
  TempDir dir;
  const std::vector<double> values = {0, 0.1 + 0.2, kInf};
  ASSERT_OK(WriteField(dir.File("f.f64"), values));
  const std::string bytes = ReadBytes(dir.File("f.f64"));
  ASSERT_EQ(bytes.size(), 3 * sizeof(double));
  std::vector<double> back(3);
  std::memcpy(back.data(), bytes.data(), bytes.size());
  EXPECT_EQ(back, values);
}

// What numpy.load checks: magic, version 1.0, a dict header ending in a
// newline, data 64-byte aligned, and the dtype and shape it says.
TEST(ResultFilesTest, FieldAndLabelsAsNpy) {
  TempDir dir;
  const std::vector<double> values = {1.5, kInf, 0.1 + 0.2, 4, 5};
  ASSERT_OK(WriteField(dir.File("f.npy"), values));
  const std::vector<uint32_t> labels = {0, 1, 4294967295u};
  ASSERT_OK(WriteLabels(dir.File("l.NPY"), labels));  // extensions in any case
  for (auto [name, descr, count, item] :
       {std::tuple{"f.npy", "'<f8'", values.size(), sizeof(double)},
        std::tuple{"l.NPY", "'<u4'", labels.size(), sizeof(uint32_t)}}) {
    const std::string bytes = ReadBytes(dir.File(name));
    ASSERT_GE(bytes.size(), 10u);
    EXPECT_EQ(bytes.substr(0, 6), "\x93NUMPY");
    EXPECT_EQ(bytes[6], 1);
    EXPECT_EQ(bytes[7], 0);
    const size_t header_len = static_cast<uint8_t>(bytes[8]) | static_cast<uint8_t>(bytes[9]) << 8;
    const size_t data_start = 10 + header_len;
    EXPECT_EQ(data_start % 64, 0u);
    const std::string header = bytes.substr(10, header_len);
    EXPECT_EQ(header.back(), '\n');
    EXPECT_THAT(header, HasSubstr(std::string("'descr': ") + descr));
    EXPECT_THAT(header, HasSubstr("'fortran_order': False"));
    EXPECT_THAT(header, HasSubstr("'shape': (" + std::to_string(count) + ",)"));
    EXPECT_EQ(bytes.size(), data_start + count * item);
  }
  const std::string f = ReadBytes(dir.File("f.npy"));
  const size_t start = f.size() - values.size() * sizeof(double);
  std::vector<double> back(values.size());
  std::memcpy(back.data(), f.data() + start, values.size() * sizeof(double));
  EXPECT_EQ(back, values);
}

TEST(ResultFilesTest, FieldAsCsvKeepsFullPrecision) {
  TempDir dir;
  ASSERT_OK(WriteField(dir.File("f.csv"), std::vector<double>{0.1 + 0.2, kInf}));
  EXPECT_THAT(Lines(ReadBytes(dir.File("f.csv"))),
              ::testing::ElementsAre("vertex,distance", "0,0.30000000000000004", "1,inf"));
}

TEST(ResultFilesTest, FieldAsColouredPly) {
  TempDir dir;
  TriangleSoup soup;
  soup.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0}};
  soup.triangles = {{0, 1, 2}, {1, 3, 2}};
  const std::vector<double> values = {0, 0.55, 2, kInf};
  ASSERT_OK(WriteField(dir.File("f.ply"), values, &soup));
  const auto lines = Lines(ReadBytes(dir.File("f.ply")));
  const auto end = std::find(lines.begin(), lines.end(), "end_header");
  ASSERT_NE(end, lines.end());
  EXPECT_THAT(std::vector<std::string>(lines.begin(), end),
              ::testing::IsSupersetOf({"element vertex 4", "element face 2", "property uchar red",
                                       "property double distance"}));
  const std::vector<std::string> body(end + 1, lines.end());
  ASSERT_EQ(body.size(), 6u);
  EXPECT_EQ(body[0], "0 0 0 0 0 0 0");                         // on an isoline (every twentieth)
  EXPECT_EQ(body[1], "1 0 0 70 140 184 0.55000000000000004");  // near: more blue than red
  EXPECT_EQ(body[3], "1 1 0 128 128 128 -1");                  // unreached: grey, -1
  EXPECT_EQ(body[4], "3 0 1 2");
  // The geometry must match the field.
  EXPECT_EQ(WriteField(dir.File("g.ply"), std::vector<double>{1, 2}, &soup).code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(WriteField(dir.File("h.ply"), values).code(), absl::StatusCode::kInvalidArgument);
}

TEST(ResultFilesTest, PolylinesAsCsvPlyAndObj) {
  TempDir dir;
  const std::vector<Vec3> points = {{0, 0, 0}, {1, 0.5, 0}, {2, 1, 0.25}};
  ASSERT_OK(WritePolyline(dir.File("p.csv"), points));
  EXPECT_THAT(Lines(ReadBytes(dir.File("p.csv"))),
              ::testing::ElementsAre("x,y,z", "0,0,0", "1,0.5,0", "2,1,0.25"));
  ASSERT_OK(WritePolyline(dir.File("p.obj"), points));
  EXPECT_THAT(Lines(ReadBytes(dir.File("p.obj"))),
              ::testing::ElementsAre("v 0 0 0", "v 1 0.5 0", "v 2 1 0.25", "l 1 2 3"));
  ASSERT_OK(WritePolyline(dir.File("p.ply"), points));
  const auto ply = Lines(ReadBytes(dir.File("p.ply")));
  EXPECT_THAT(ply, ::testing::Contains("element edge 2"));
  EXPECT_EQ(ply.back(), "1 2");
}

TEST(ResultFilesTest, UnknownExtensionsAreRefusedBeforeWriting) {
  TempDir dir;
  for (const std::string name : {"f.txt", "f", "dir.npy/f", "f.f32"}) {
    absl::Status s = WriteField(dir.File(name), std::vector<double>{1});
    EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << name;
    EXPECT_THAT(std::string(s.message()), HasSubstr(".f64, .npy, .csv, .ply")) << name;
    EXPECT_FALSE(std::ifstream(dir.File(name)).good()) << name;
  }
  EXPECT_THAT(std::string(WriteLabels(dir.File("l.f64"), std::vector<uint32_t>{1}).message()),
              HasSubstr("'.f64'"));
  EXPECT_EQ(WritePolyline(dir.File("p.npy"), std::vector<Vec3>{}).code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_OK(CheckFieldPath("x.ply", true));
  EXPECT_FALSE(CheckFieldPath("x.ply", false).ok());
}

}  // namespace
}  // namespace geodesic
