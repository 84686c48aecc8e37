// Part files of a distributed build as untrusted input: they read back as
// written, and a truncated file, a flipped byte in the header or the edges,
// and a part of the old format are each refused with the right code and a
// message naming the file. Parts that went through files merge to the
// graph a whole build makes.
#include "core/dgg/dgg_part_file.h"

#include <cstring>
#include <fstream>
#include <iterator>
#include <string>
#include <tuple>
#include <vector>

#include "absl/strings/str_cat.h"
#include "core/base/file_header.h"
#include "core/dgg/graph_file.h"
#include "core/query/build_dgg.h"
#include "tests/core/test_util.h"
#include "xxhash.h"

namespace geodesic {
namespace {

using ::testing::HasSubstr;
using testing::ReadBytes;
using testing::TempDir;
using testing::WriteBytes;

// The header of version 3: magic, version, endian tag, ..., and its last
// field, the header checksum.
constexpr size_t kHeaderBytes = 104;

class DggPartFileTest : public ::testing::Test {
 protected:
  void SetUp() override {
    mesh_ = testing::Cube(3);
    options_.params.epsilon = 0.05;
    options_.threads = 2;
  }

  // Part `index` of 3, written to a file of the temp dir.
  std::string WritePart(uint32_t index, DggCandidatePart* out = nullptr) {
    auto part = BuildDggCandidatePart(mesh_, options_, index, 3);
    EXPECT_TRUE(part.ok()) << part.status();
    const std::string path = dir_.File(absl::StrCat("p", index, ".part"));
    EXPECT_TRUE(WriteDggPart(*part, path).ok());
    if (out) *out = *std::move(part);
    return path;
  }

  // `bytes` written as damaged.part: ReadDggPart's status, which must fail
  // naming that file; ReadDggPartIndex's when `index_too`.
  absl::Status Refused(const std::string& bytes, bool index_too = true) {
    const std::string path = dir_.File("damaged.part");
    WriteBytes(path, bytes);
    const absl::Status s = ReadDggPart(path).status();
    EXPECT_FALSE(s.ok());
    EXPECT_THAT(std::string(s.message()), HasSubstr(path));
    if (index_too) {
      const absl::Status index = ReadDggPartIndex(path).status();
      EXPECT_EQ(index.code(), s.code()) << index;
      EXPECT_THAT(std::string(index.message()), HasSubstr(path));
    }
    return s;
  }

  Mesh mesh_;
  DggBuildOptions options_;
  TempDir dir_;
};

TEST_F(DggPartFileTest, APartReadsBackAsWrittenAndItsIndexWithoutEdges) {
  DggCandidatePart written;
  const std::string path = WritePart(1, &written);
  ASSERT_GT(written.edges.size(), 0u);
  EXPECT_EQ(ReadBytes(path).size(),
            kHeaderBytes + written.offsets.size() * 8 + written.edges.size() * sizeof(DggHalfEdge));
  auto read = ReadDggPart(path);
  ASSERT_OK(read);
  EXPECT_EQ(read->params, written.params);
  EXPECT_EQ(read->mesh_fingerprint, written.mesh_fingerprint);
  EXPECT_EQ(std::tie(read->num_vertices, read->begin, read->end),
            std::tie(written.num_vertices, written.begin, written.end));
  EXPECT_EQ(read->windows_created, written.windows_created);
  EXPECT_EQ(read->offsets, written.offsets);
  ASSERT_EQ(read->edges.size(), written.edges.size());
  EXPECT_EQ(std::memcmp(read->edges.data(), written.edges.data(),
                        written.edges.size() * sizeof(DggHalfEdge)),
            0);
  auto index = ReadDggPartIndex(path);
  ASSERT_OK(index);
  EXPECT_EQ(index->offsets, written.offsets);
  EXPECT_EQ(std::tie(index->begin, index->end), std::tie(written.begin, written.end));
  EXPECT_TRUE(index->edges.empty());
}

TEST_F(DggPartFileTest, PartsReadFromFilesMergeToTheWholeBuildsGraph) {
  std::vector<DggPartSource> sources;
  for (uint32_t i : {2u, 0u, 1u}) {
    const std::string path = WritePart(i);
    auto index = ReadDggPartIndex(path);
    ASSERT_OK(index);
    sources.push_back({path, *std::move(index), [path] { return ReadDggPart(path); }});
  }
  auto merged = MergeDggParts(mesh_, std::move(sources), options_);
  ASSERT_OK(merged);
  auto whole = BuildDgg(mesh_, options_);
  ASSERT_OK(whole);
  ASSERT_OK(GraphFile::Write(**merged, dir_.File("merged.dgg")));
  ASSERT_OK(GraphFile::Write(**whole, dir_.File("whole.dgg")));
  EXPECT_TRUE(ReadBytes(dir_.File("merged.dgg")) == ReadBytes(dir_.File("whole.dgg")));
}

TEST_F(DggPartFileTest, ATruncatedPartIsDataLoss) {
  const std::string good = ReadBytes(WritePart(0));
  // In the edges, at the end of the offsets, in the header, in the magic,
  // nothing at all.
  for (size_t size : {good.size() - 1, good.size() - 16, kHeaderBytes + 8, kHeaderBytes - 1,
                      size_t{20}, size_t{5}, size_t{0}}) {
    const absl::Status s = Refused(good.substr(0, size));
    EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss) << size << ": " << s;
  }
  // The common header's check names both sizes.
  EXPECT_THAT(std::string(Refused(good.substr(0, good.size() - 1)).message()),
              HasSubstr(absl::StrCat("header says ", good.size(), " bytes but the file has ",
                                     good.size() - 1)));
  // And a part with bytes appended.
  EXPECT_EQ(Refused(good + "x").code(), absl::StatusCode::kDataLoss);
}

TEST_F(DggPartFileTest, AFlippedHeaderByteIsRefused) {
  const std::string good = ReadBytes(WritePart(0));
  for (size_t at = 0; at < kHeaderBytes; ++at) {
    std::string bytes = good;
    bytes[at] ^= 0x10;
    const absl::Status s = Refused(bytes);
    // The version and the endian tag (bytes 8 to 15) make another format,
    // which FAILED_PRECONDITION names; any other byte is damage.
    const bool format = at >= 8 && at < 16;
    EXPECT_EQ(s.code(),
              format ? absl::StatusCode::kFailedPrecondition : absl::StatusCode::kDataLoss)
        << "byte " << at << ": " << s;
    if (at < 8) {
      EXPECT_THAT(std::string(s.message()), HasSubstr("is not a geodesicd part file"));
    }
    if (at >= 16) {
      EXPECT_THAT(std::string(s.message()), HasSubstr("header checksum mismatch"));
    }
  }
}

TEST_F(DggPartFileTest, AFlippedEdgeOrOffsetByteIsDataLossWhenTheEdgesAreRead) {
  DggCandidatePart part;
  const std::string good = ReadBytes(WritePart(2, &part));
  const size_t edges_at = kHeaderBytes + part.offsets.size() * 8;
  for (size_t at : {edges_at, edges_at + 5, good.size() / 2 + edges_at / 2, good.size() - 7}) {
    std::string bytes = good;
    bytes[at] ^= 0x01;
    // The index leaves the edges unread: only the whole read checks them.
    const absl::Status s = Refused(bytes, /*index_too=*/false);
    EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss) << "byte " << at << ": " << s;
    EXPECT_THAT(std::string(s.message()),
                HasSubstr("damaged.part: checksum mismatch in the edges"));
    EXPECT_OK(ReadDggPartIndex(dir_.File("damaged.part")));
  }
  std::string bytes = good;
  bytes[kHeaderBytes + 8] ^= 0x01;  // the second offset
  EXPECT_EQ(Refused(bytes, /*index_too=*/false).code(), absl::StatusCode::kDataLoss);
}

// The header of part format version 2, as those builds wrote it: the same
// fields but the file's size.
struct PartHeaderV2 {
  char magic[8];
  uint32_t version;
  uint32_t endian;
  uint64_t mesh_fingerprint;
  StoredDggParams params;
  uint32_t num_vertices, begin, end, reserved;
  uint64_t windows_created;
  uint64_t num_edges;
  uint64_t payload_checksum;
  uint64_t header_checksum;
};
static_assert(sizeof(PartHeaderV2) == 96);

TEST_F(DggPartFileTest, APartOfTheOldFormatIsFailedPreconditionNamingBothVersions) {
  DggCandidatePart part;
  const std::string good = ReadBytes(WritePart(1, &part));
  PartHeaderV2 h{};
  std::memcpy(h.magic, good.data(), 8);
  h.version = 2;
  h.endian = kEndianTag;
  h.mesh_fingerprint = part.mesh_fingerprint;
  h.params = StoredDggParams::Of(part.params);
  h.num_vertices = part.num_vertices;
  h.begin = part.begin;
  h.end = part.end;
  h.windows_created = part.windows_created;
  h.num_edges = part.edges.size();
  h.payload_checksum = XXH3_64bits(good.data() + kHeaderBytes, good.size() - kHeaderBytes);
  h.header_checksum = XXH3_64bits(&h, sizeof(h));  // of the header with this field zero
  std::string v2(reinterpret_cast<const char*>(&h), sizeof(h));
  v2 += good.substr(kHeaderBytes);  // the same offsets and edges
  for (const std::string& bytes : {v2, v2.substr(0, sizeof(h))}) {
    const absl::Status s = Refused(bytes);
    EXPECT_EQ(s.code(), absl::StatusCode::kFailedPrecondition) << s;
    EXPECT_THAT(std::string(s.message()),
                HasSubstr(absl::StrCat("damaged.part has part file format version 2; this build "
                                       "reads version ",
                                       kPartFormatVersion)));
  }
  EXPECT_EQ(kPartFormatVersion, 3u);
}

TEST_F(DggPartFileTest, ForeignAndMissingFilesAreRefusedByName) {
  EXPECT_THAT(std::string(Refused(std::string(4096, 'x')).message()),
              HasSubstr("is not a geodesicd part file"));
  const auto missing = ReadDggPart(dir_.File("absent.part"));
  EXPECT_EQ(missing.status().code(), absl::StatusCode::kNotFound) << missing.status();
  EXPECT_THAT(std::string(missing.status().message()), HasSubstr("absent.part"));
}

}  // namespace
}  // namespace geodesic
