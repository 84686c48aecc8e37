// Uploads as transactions (UploadAssembler), and what registration refuses:
// files that are not regular files, names and paths that mean something
// else, meshes with no faces, and client input echoed at length.
#include "server/meshes/upload.h"

#include <sys/stat.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "server/api/convert.h"
#include "server/base/echo.h"
#include "server/meshes/mesh_registry.h"

namespace geodesic::server {
namespace {

using ::testing::HasSubstr;
using ::testing::Not;

const std::string kTriangle = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";

v1::UploadMeshRequest First(const std::string& data, uint64_t total, const std::string& sha256) {
  v1::UploadMeshRequest m;
  m.set_name("tri");
  m.set_format("obj");
  m.set_total_bytes(total);
  m.set_sha256(sha256);
  m.set_data(data);
  return m;
}

v1::UploadMeshRequest Data(const std::string& data) {
  v1::UploadMeshRequest m;
  m.set_data(data);
  return m;
}

TEST(Sha256Test, MatchesTheStandardVector) {
  EXPECT_EQ(Sha256Hex("abc"), "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
}

TEST(UploadAssemblerTest, AcceptsExactlyTheDeclaredBytesInChunks) {
  UploadAssembler upload(1 << 20);
  auto first = First(kTriangle.substr(0, 10), kTriangle.size(), Sha256Hex(kTriangle));
  ASSERT_TRUE(upload.Add(first).ok());
  auto rest = Data(kTriangle.substr(10));
  ASSERT_TRUE(upload.Add(rest).ok());
  ASSERT_TRUE(upload.Finish().ok());
  EXPECT_EQ(upload.bytes(), kTriangle);
  EXPECT_EQ(upload.name(), "tri");
  EXPECT_FALSE(upload.arrays());
}

TEST(UploadAssemblerTest, AnUploadTooSlowOnAverageIsRefusedAfterItsGrace) {
  UploadAssembler upload(1 << 30);
  const std::string big(1 << 20, 'x');
  auto first = First(big.substr(0, 10), big.size(), Sha256Hex(big));
  ASSERT_TRUE(upload.Add(first).ok());
  EXPECT_EQ(upload.received_bytes(), 10u);
  // A slow start is allowed its grace; ten bytes in a minute are not.
  EXPECT_TRUE(CheckUploadRate(upload, absl::Seconds(5)).ok());
  const absl::Status slow = CheckUploadRate(upload, absl::Seconds(60));
  EXPECT_EQ(slow.code(), absl::StatusCode::kDeadlineExceeded);
  EXPECT_THAT(slow.message(), HasSubstr("bytes/s"));
  // At a modest pace it goes on.
  auto rest = Data(big.substr(10));
  ASSERT_TRUE(upload.Add(rest).ok());
  EXPECT_TRUE(CheckUploadRate(upload, absl::Seconds(60)).ok());
  EXPECT_TRUE(upload.Finish().ok());
}

TEST(UploadAssemblerTest, AnUploadCutShortIsRefused) {
  UploadAssembler upload(1 << 20);
  auto first = First(kTriangle.substr(0, 10), kTriangle.size(), Sha256Hex(kTriangle));
  ASSERT_TRUE(upload.Add(first).ok());
  absl::Status s = upload.Finish();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(s.message(), HasSubstr("ended after 10 of"));
}

TEST(UploadAssemblerTest, MoreThanDeclaredIsRefusedAtOnce) {
  UploadAssembler upload(1 << 20);
  auto first = First(kTriangle, kTriangle.size() - 1, Sha256Hex(kTriangle));
  absl::Status s = upload.Add(first);
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(s.message(), HasSubstr("more than"));
}

TEST(UploadAssemblerTest, AWrongChecksumIsRefused) {
  UploadAssembler upload(1 << 20);
  auto first = First(kTriangle, kTriangle.size(), Sha256Hex(kTriangle + " "));
  ASSERT_TRUE(upload.Add(first).ok());
  absl::Status s = upload.Finish();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(s.message(), HasSubstr("SHA-256"));
}

TEST(UploadAssemblerTest, ASizeOverTheLimitIsRefusedFromTheFirstMessage) {
  UploadAssembler upload(100);
  auto first = First("", 101, Sha256Hex(""));
  absl::Status s = upload.Add(first);
  EXPECT_EQ(s.code(), absl::StatusCode::kResourceExhausted);
  EXPECT_THAT(s.message(), HasSubstr("--max-upload-bytes"));
}

TEST(UploadAssemblerTest, AnUndeclaredUploadNamesTheMissingField) {
  {
    UploadAssembler upload(1 << 20);
    auto first = First(kTriangle, 0, Sha256Hex(kTriangle));
    EXPECT_THAT(upload.Add(first).message(), HasSubstr("total_bytes"));
  }
  {
    UploadAssembler upload(1 << 20);
    auto first = First(kTriangle, kTriangle.size(), "");
    EXPECT_THAT(upload.Add(first).message(), HasSubstr("sha256"));
  }
  {
    UploadAssembler upload(1 << 20);
    auto first = First(kTriangle, kTriangle.size(), "abc");
    EXPECT_THAT(upload.Add(first).message(), HasSubstr("64 hex digits"));
  }
  UploadAssembler upload(1 << 20);
  EXPECT_EQ(upload.Finish().code(), absl::StatusCode::kInvalidArgument);
}

TEST(UploadAssemblerTest, OnlyTheFirstMessageCarriesTheHeader) {
  UploadAssembler upload(1 << 20);
  auto first = First("", kTriangle.size(), Sha256Hex(kTriangle));
  ASSERT_TRUE(upload.Add(first).ok());
  auto renamed = Data(kTriangle);
  renamed.set_name("other");
  EXPECT_EQ(upload.Add(renamed).code(), absl::StatusCode::kInvalidArgument);
}

TEST(UploadAssemblerTest, ArraysAreHashedVerticesThenFaces) {
  const std::vector<double> vertices = {0, 0, 0, 1, 0, 0, 0, 1, 0};
  const std::vector<uint32_t> faces = {0, 1, 2};
  UploadAssembler upload(1 << 20);
  v1::UploadMeshRequest first;
  first.set_name("tri");
  first.set_total_bytes(8 * vertices.size() + 4 * faces.size());
  first.set_sha256(Sha256HexOfArrays(vertices, faces));
  // Faces may come first: the hash is over vertices, then faces.
  first.mutable_faces()->Add(faces.begin(), faces.end());
  ASSERT_TRUE(upload.Add(first).ok());
  v1::UploadMeshRequest rest;
  rest.mutable_vertices()->Add(vertices.begin(), vertices.end());
  ASSERT_TRUE(upload.Add(rest).ok());
  ASSERT_TRUE(upload.Finish().ok());
  EXPECT_TRUE(upload.arrays());
  EXPECT_EQ(upload.vertices(), vertices);
  EXPECT_EQ(upload.faces(), faces);
}

// As the HTTP gateway sends an upload: each message within
// kUploadMessageBytes, the header only in the first, and what the
// assembler puts together is the payload split.
TEST(SplitUploadTest, MessagesStayWithinTheirSizeAndReassembleThePayload) {
  const std::string data(2 * kUploadMessageBytes + 12345, 'x');
  std::vector<double> vertices(kUploadMessageBytes / 8 + 7);
  for (size_t i = 0; i < vertices.size(); ++i) vertices[i] = 0.5 * i;
  std::vector<uint32_t> faces(kUploadMessageBytes / 4 + 11);
  for (size_t i = 0; i < faces.size(); ++i) faces[i] = i % 97;
  for (bool arrays : {false, true}) {
    v1::UploadMeshRequest header;
    header.set_name("split");
    if (arrays) {
      header.set_total_bytes(8 * vertices.size() + 4 * faces.size());
      header.set_sha256(Sha256HexOfArrays(vertices, faces));
    } else {
      header.set_format("obj");
      header.set_total_bytes(data.size());
      header.set_sha256(Sha256Hex(data));
    }
    UploadAssembler upload(uint64_t{64} << 20);
    int messages = 0;
    absl::Status status;
    SplitUpload(header, arrays ? std::string_view() : data,
                arrays ? vertices : std::vector<double>{}, arrays ? faces : std::vector<uint32_t>{},
                [&](const v1::UploadMeshRequest& m) {
                  EXPECT_LE(m.data().size() + 8 * m.vertices_size() + 4 * m.faces_size(),
                            kUploadMessageBytes);
                  EXPECT_EQ(m.name().empty(), messages > 0);
                  ++messages;
                  v1::UploadMeshRequest copy = m;
                  status.Update(upload.Add(copy));
                  return status.ok();
                });
    ASSERT_TRUE(status.ok()) << status;
    EXPECT_EQ(messages, 3) << (arrays ? "arrays" : "bytes");
    ASSERT_TRUE(upload.Finish().ok());
    if (arrays) {
      EXPECT_EQ(upload.vertices(), vertices);
      EXPECT_EQ(upload.faces(), faces);
    } else {
      EXPECT_EQ(upload.bytes(), data);
    }
  }
}

TEST(UploadAssemblerTest, BytesAndArraysDoNotMix) {
  UploadAssembler upload(1 << 20);
  auto first = First("v", 100, Sha256Hex(""));
  first.add_vertices(1.0);
  EXPECT_EQ(upload.Add(first).code(), absl::StatusCode::kInvalidArgument);
}

TEST(EchoTest, RepeatsAtMost80CharactersEscaped) {
  EXPECT_EQ(Echo("spot.obj"), "spot.obj");
  const std::string echoed = Echo(std::string(10240, 'n'));
  EXPECT_THAT(echoed, HasSubstr(std::string(80, 'n')));
  EXPECT_THAT(echoed, Not(HasSubstr(std::string(81, 'n'))));
  EXPECT_THAT(echoed, HasSubstr("10240 bytes"));
  EXPECT_EQ(Echo(std::string("a\0z", 3)), "a\\x00z");
}

class RegistryFilesTest : public ::testing::Test {
 protected:
  void SetUp() override {
    char pattern[] = "/tmp/geodesic-upload-test-XXXXXX";
    ASSERT_NE(::mkdtemp(pattern), nullptr);
    root_ = pattern;
    std::filesystem::copy_file(std::string(GEODESIC_SOURCE_DIR) + "/data/spot.obj",
                               root_ / "spot.obj");
    std::ofstream(root_ / "points.obj") << "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
    ASSERT_EQ(::mkfifo((root_ / "pipe.obj").c_str(), 0600), 0);
  }
  void TearDown() override { std::filesystem::remove_all(root_); }

  std::filesystem::path root_;
};

TEST_F(RegistryFilesTest, OnlyRegularFilesAreOpened) {
  MeshRegistry registry(root_.string());
  // Refused at once, not waited on for a writer.
  auto fifo = registry.RegisterPath("pipe", "pipe.obj");
  EXPECT_EQ(fifo.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(fifo.status().message(), HasSubstr("'pipe.obj' is a FIFO"));
  auto dir = registry.RegisterPath("dot", ".");
  EXPECT_EQ(dir.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(dir.status().message(), HasSubstr("is a directory"));
  EXPECT_TRUE(registry.RegisterPath("spot", "spot.obj").ok());
}

TEST_F(RegistryFilesTest, NamesAndPathsThatMeanSomethingElseAreRefused) {
  MeshRegistry registry(root_.string());
  for (const std::string& name : std::vector<std::string>{".", "..", std::string("sp\0t", 4)}) {
    EXPECT_EQ(registry.RegisterPath(name, "spot.obj").status().code(),
              absl::StatusCode::kInvalidArgument)
        << Echo(name);
    EXPECT_EQ(registry.RegisterBytes(name, "obj", kTriangle).status().code(),
              absl::StatusCode::kInvalidArgument)
        << Echo(name);
  }
  auto nul = registry.RegisterPath("nul", std::string("spot.obj\0.txt", 13));
  EXPECT_EQ(nul.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(nul.status().message(), HasSubstr("NUL"));
  EXPECT_TRUE(registry.List().empty());
}

TEST_F(RegistryFilesTest, AMeshWithNoFacesIsRefused) {
  MeshRegistry registry(root_.string());
  auto points = registry.RegisterPath("points", "points.obj");
  EXPECT_EQ(points.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(points.status().message(), HasSubstr("no faces"));
  auto uploaded = registry.RegisterBytes("points", "obj", "v 0 0 0\n");
  EXPECT_THAT(uploaded.status().message(), HasSubstr("no faces"));
  auto arrays = registry.RegisterArrays("points", {0, 0, 0}, {});
  EXPECT_THAT(arrays.status().message(), HasSubstr("no faces"));
  EXPECT_TRUE(registry.List().empty());
}

// The triangle of kTriangle as a GIFTI surface (ASCII, to be readable here).
std::string TriangleGifti() {
  const char* array =
      "<DataArray Intent=\"NIFTI_INTENT_%s\" DataType=\"NIFTI_TYPE_%s\" "
      "ArrayIndexingOrder=\"RowMajorOrder\" Dimensionality=\"2\" Dim0=\"%d\" Dim1=\"3\" "
      "Encoding=\"ASCII\"><Data>%s</Data></DataArray>\n";
  return "<?xml version=\"1.0\"?>\n<GIFTI Version=\"1.0\" NumberOfDataArrays=\"2\">\n" +
         absl::StrFormat(array, "POINTSET", "FLOAT32", 3, "0 0 0 1 0 0 0 1 0") +
         absl::StrFormat(array, "TRIANGLE", "INT32", 1, "0 1 2") + "</GIFTI>\n";
}

// gii is a mesh format like the others: by path under the root (x.surf.gii)
// and as uploaded bytes, giving the mesh the OBJ of the same triangle gives.
TEST_F(RegistryFilesTest, GiftiSurfacesRegisterByPathAndBytes) {
  MeshRegistry registry(root_.string());
  std::ofstream(root_ / "tri.surf.gii") << TriangleGifti();
  auto by_path = registry.RegisterPath("tri-path", "tri.surf.gii");
  ASSERT_TRUE(by_path.ok()) << by_path.status();
  EXPECT_EQ((*by_path)->format, "gii");
  auto by_bytes = registry.RegisterBytes("tri-bytes", "gii", TriangleGifti());
  ASSERT_TRUE(by_bytes.ok()) << by_bytes.status();
  auto obj = registry.RegisterBytes("tri-obj", "obj", kTriangle);
  ASSERT_TRUE(obj.ok()) << obj.status();
  EXPECT_EQ((*by_path)->fingerprint, (*obj)->fingerprint);
  EXPECT_EQ((*by_bytes)->fingerprint, (*obj)->fingerprint);
  auto torn = registry.RegisterBytes("torn", "gii", TriangleGifti().substr(0, 120));
  EXPECT_EQ(torn.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(torn.status().message(), HasSubstr("not a readable GIFTI file"));
}

TEST_F(RegistryFilesTest, ErrorsRepeatAtMost80CharactersOfTheInput) {
  MeshRegistry registry(root_.string());
  const std::string long_input(10240, 'n');
  for (const absl::Status& s : {registry.RegisterPath(long_input, "spot.obj").status(),
                                registry.RegisterPath("long", long_input).status(),
                                registry.RegisterPath("long", "sub/" + long_input).status(),
                                registry.RegisterBytes("long", long_input, kTriangle).status(),
                                registry.Get(long_input).status(), registry.Remove(long_input)}) {
    EXPECT_FALSE(s.ok());
    EXPECT_THAT(s.message(), Not(HasSubstr(std::string(81, 'n'))));
  }
}

TEST_F(RegistryFilesTest, ArraysBecomeTheMeshTheyDescribe) {
  MeshRegistry registry(root_.string());
  const std::vector<double> vertices = {0, 0, 0, 1, 0, 0, 0, 1, 0};
  auto m = registry.RegisterArrays("tri", vertices, {0, 1, 2});
  ASSERT_TRUE(m.ok()) << m.status();
  EXPECT_EQ((*m)->mesh->num_vertices(), 3u);
  EXPECT_EQ((*m)->format, "arrays");
  auto tri = registry.RegisterBytes("tri-file", "obj", kTriangle);
  ASSERT_TRUE(tri.ok()) << tri.status();
  EXPECT_EQ((*m)->fingerprint, (*tri)->fingerprint);
  EXPECT_EQ(registry.RegisterArrays("bad", vertices, {0, 1, 3}).status().code(),
            absl::StatusCode::kOutOfRange);
  EXPECT_EQ(registry.RegisterArrays("bad", {0, 0}, {0, 1, 2}).status().code(),
            absl::StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace geodesic::server
