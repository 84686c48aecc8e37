#include "core/mesh/mesh_io.h"

#include <signal.h>
#include <sys/stat.h>
#include <unistd.h>

#include <OpenMesh/Core/IO/IOManager.hh>
#include <OpenMesh/Core/IO/importer/BaseImporter.hh>
#include <OpenMesh/Core/System/omstream.hh>
#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <numbers>
#include <numeric>
#include <optional>
#include <sstream>

#include "absl/cleanup/cleanup.h"
#include "absl/container/flat_hash_map.h"
#include "absl/container/flat_hash_set.h"
#include "absl/status/status.h"
#include "absl/strings/ascii.h"
#include "absl/strings/escaping.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "core/base/status.h"
#include "core/mesh/gifti_files.h"

namespace geodesic {
namespace {

using OpenMesh::VertexHandle;

// Records what OpenMesh's readers find, in file order, without building any
// topology: OpenMesh's own kernel duplicates vertices and drops faces on
// non-manifold input, which would break "vertex ids are file order".
class SoupImporter : public OpenMesh::IO::BaseImporter {
 public:
  explicit SoupImporter(TriangleSoup* soup) : soup_(soup) {}

  VertexHandle add_vertex(const OpenMesh::Vec3f& p) override {
    return add_vertex(OpenMesh::Vec3d(p[0], p[1], p[2]));
  }
  VertexHandle add_vertex(const OpenMesh::Vec3d& p) override {
    soup_->positions.push_back({p[0], p[1], p[2]});
    return VertexHandle(static_cast<int>(soup_->positions.size() - 1));
  }
  VertexHandle add_vertex() override { return add_vertex(OpenMesh::Vec3d(0, 0, 0)); }
  OpenMesh::HalfedgeHandle add_edge(VertexHandle, VertexHandle) override {
    return OpenMesh::HalfedgeHandle();
  }
  OpenMesh::FaceHandle add_face(const VHandles& v) override {
    ++input_faces_;
    if (v.size() < 3) {
      if (first_error_.empty()) {
        first_error_ = absl::StrFormat("face %u has only %u vertices", input_faces_ - 1, v.size());
      }
      return OpenMesh::FaceHandle();
    }
    // More corners than the file has vertices: a garbled count (found by
    // tests/fuzz; its fan would be hundreds of millions of triangles).
    if (v.size() > soup_->positions.size()) {
      if (first_error_.empty()) {
        first_error_ = absl::StrFormat("face %u has %u corners but the file has only %u vertices",
                                       input_faces_ - 1, v.size(), soup_->positions.size());
      }
      return OpenMesh::FaceHandle();
    }
    for (VertexHandle h : v) {
      if (!h.is_valid() || static_cast<size_t>(h.idx()) >= soup_->positions.size()) {
        if (first_error_.empty()) {
          first_error_ =
              absl::StrFormat("face %u refers to vertex %d, but the file has %u vertices",
                              input_faces_ - 1, h.idx(), soup_->positions.size());
        }
        return OpenMesh::FaceHandle();
      }
    }
    if (v.size() > 3) ++polygons_;
    // Fan triangulation keeps the face's orientation and corner order.
    for (size_t k = 1; k + 1 < v.size(); ++k) {
      soup_->triangles.push_back({static_cast<VertexId>(v[0].idx()),
                                  static_cast<VertexId>(v[k].idx()),
                                  static_cast<VertexId>(v[k + 1].idx())});
    }
    return OpenMesh::FaceHandle(static_cast<int>(soup_->triangles.size() - 1));
  }
  OpenMesh::FaceHandle add_face(OpenMesh::HalfedgeHandle) override {
    return OpenMesh::FaceHandle();
  }
  void add_face_texcoords(OpenMesh::FaceHandle, VertexHandle,
                          const std::vector<OpenMesh::Vec2f>&) override {}
  void add_face_texcoords(OpenMesh::FaceHandle, VertexHandle,
                          const std::vector<OpenMesh::Vec3f>&) override {}
  void set_face_texindex(OpenMesh::FaceHandle, int) override {}
  void set_point(VertexHandle h, const OpenMesh::Vec3f& p) override {
    if (h.is_valid() && static_cast<size_t>(h.idx()) < soup_->positions.size()) {
      soup_->positions[h.idx()] = {p[0], p[1], p[2]};
    }
  }
  void set_halfedge(VertexHandle, OpenMesh::HalfedgeHandle) override {}
  void set_normal(VertexHandle, const OpenMesh::Vec3f&) override {}
  void set_normal(VertexHandle, const OpenMesh::Vec3d&) override {}
  void set_color(VertexHandle, const OpenMesh::Vec3uc&) override {}
  void set_color(VertexHandle, const OpenMesh::Vec4uc&) override {}
  void set_color(VertexHandle, const OpenMesh::Vec3f&) override {}
  void set_color(VertexHandle, const OpenMesh::Vec4f&) override {}
  void set_texcoord(VertexHandle, const OpenMesh::Vec2f&) override {}
  void set_status(VertexHandle, const OpenMesh::Attributes::StatusInfo&) override {}
  void set_next(OpenMesh::HalfedgeHandle, OpenMesh::HalfedgeHandle) override {}
  void set_face(OpenMesh::HalfedgeHandle, OpenMesh::FaceHandle) override {}
  void request_face_texcoords2D() override {}
  void set_texcoord(OpenMesh::HalfedgeHandle, const OpenMesh::Vec2f&) override {}
  void set_texcoord(VertexHandle, const OpenMesh::Vec3f&) override {}
  void set_texcoord(OpenMesh::HalfedgeHandle, const OpenMesh::Vec3f&) override {}
  void set_status(OpenMesh::HalfedgeHandle, const OpenMesh::Attributes::StatusInfo&) override {}
  void set_color(OpenMesh::EdgeHandle, const OpenMesh::Vec3uc&) override {}
  void set_color(OpenMesh::EdgeHandle, const OpenMesh::Vec4uc&) override {}
  void set_color(OpenMesh::EdgeHandle, const OpenMesh::Vec3f&) override {}
  void set_color(OpenMesh::EdgeHandle, const OpenMesh::Vec4f&) override {}
  void set_status(OpenMesh::EdgeHandle, const OpenMesh::Attributes::StatusInfo&) override {}
  void set_normal(OpenMesh::FaceHandle, const OpenMesh::Vec3f&) override {}
  void set_normal(OpenMesh::FaceHandle, const OpenMesh::Vec3d&) override {}
  void set_color(OpenMesh::FaceHandle, const OpenMesh::Vec3uc&) override {}
  void set_color(OpenMesh::FaceHandle, const OpenMesh::Vec4uc&) override {}
  void set_color(OpenMesh::FaceHandle, const OpenMesh::Vec3f&) override {}
  void set_color(OpenMesh::FaceHandle, const OpenMesh::Vec4f&) override {}
  void set_status(OpenMesh::FaceHandle, const OpenMesh::Attributes::StatusInfo&) override {}
  void add_texture_information(int, std::string) override {}
  size_t n_vertices() const override { return soup_->positions.size(); }
  size_t n_faces() const override { return soup_->triangles.size(); }
  size_t n_edges() const override { return 0; }

  size_t input_faces() const { return input_faces_; }
  size_t polygons() const { return polygons_; }
  const std::string& first_error() const { return first_error_; }

 private:
  TriangleSoup* soup_;
  size_t input_faces_ = 0;
  size_t polygons_ = 0;
  std::string first_error_;
};

// OpenMesh's readers are chatty on stderr; the daemon must not be.
void SilenceOpenMesh() {
  static bool done = [] {
    omlog().disable();
    omout().disable();
    omerr().disable();
    return true;
  }();
  (void)done;
}

// OpenMesh parses ASCII coordinates as float (24-bit mantissa), moving
// vertices by up to 6e-8 relative, so exact distances would disagree with
// tools that read doubles. For the ASCII formats we read the coordinates
// again in double precision (and check them: OpenMesh silently skips a vertex
// line it cannot parse, which would shift every later id).
// OpenMesh's OBJ reader asserts (aborting the process) on a corner without
// a vertex index ("/2") and reads a stale index after an unparsable one, so
// face corners are checked against the OBJ grammar first (found by
// tests/fuzz). Trailing comments on face lines are refused too: OpenMesh
// would read their numbers as corners.
bool IsObjFaceCorner(absl::string_view corner) {
  std::vector<absl::string_view> parts = absl::StrSplit(corner, '/');
  if (parts.size() > 3) return false;
  for (size_t k = 0; k < parts.size(); ++k) {
    int index;
    if (parts[k].empty() ? k == 0 : !absl::SimpleAtoi(parts[k], &index)) return false;
  }
  return true;
}

struct AsciiVertices {
  bool available = false;
  std::vector<Vec3> positions;
};

// Appends the vertex whose three coordinates start `text` (line
// `line_number` of `name`), read as doubles.
absl::Status ParseAsciiVertex(const std::string& text, const std::string& name, size_t line_number,
                              std::vector<Vec3>& positions) {
  std::istringstream fields(text);
  std::string t[3];
  fields >> t[0] >> t[1] >> t[2];
  double x[3];
  for (int k = 0; k < 3; ++k) {
    char* end = nullptr;
    x[k] = std::strtod(t[k].c_str(), &end);
    if (t[k].empty() || end != t[k].c_str() + t[k].size() || !std::isfinite(x[k])) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s line %u: vertex %u has a bad coordinate '%s'", name, line_number,
                          positions.size(), t[k]));
    }
  }
  positions.push_back({x[0], x[1], x[2]});
  return absl::OkStatus();
}

absl::StatusOr<AsciiVertices> ScanObjVertices(std::ifstream& in, const std::string& name) {
  AsciiVertices out;
  std::string line;
  size_t line_number = 0;
  while (std::getline(in, line)) {
    ++line_number;
    if (line.size() > 2 && line[0] == 'v' && (line[1] == ' ' || line[1] == '\t')) {
      absl::Status s = ParseAsciiVertex(line.substr(2), name, line_number, out.positions);
      if (!s.ok()) return s;
    }
    std::istringstream fields(line);
    std::string word;
    if (!(fields >> word) || word != "f") continue;
    while (fields >> word) {
      if (!IsObjFaceCorner(word)) {
        return absl::InvalidArgumentError(absl::StrFormat(
            "%s line %u: face corner '%s' is not v, v/vt, v//vn or v/vt/vn with integer indices",
            name, line_number, absl::CHexEscape(word.substr(0, 30))));
      }
    }
  }
  out.available = true;
  return out;
}

// Whether `word` is an OFF keyword, [ST][C][N][4][n]OFF, of at most six
// characters: anything else before "OFF" (a control byte, found by fuzzing)
// is not OFF.
bool IsOffKeyword(std::string_view word) {
  return word.size() <= 6 && word.ends_with("OFF") &&
         word.substr(0, word.size() - 3).find_first_not_of("STCN4n") == std::string_view::npos;
}

// An OFF header: the keyword, then the vertex, face and edge counts, on one
// line or more; '#' starts a comment. A variant (COFF, NOFF, ...) has values
// besides the position on each vertex line, which OpenMesh keeps.
struct OffHeader {
  bool variant = false;
  size_t vertices = 0;  // 0 if no count is found
};

// Nothing may follow the counts on their line: OpenMesh reads on from there
// into the faces, and garbage there ran it out of memory (found by fuzzing),
// where the face check (which reads the lines after the header) never saw it.
absl::StatusOr<OffHeader> ReadOffHeader(std::ifstream& in, const std::string& name,
                                        size_t& line_number) {
  std::string line;
  std::vector<std::string> words;
  while (std::getline(in, line)) {
    ++line_number;
    if (auto hash = line.find('#'); hash != std::string::npos) line.resize(hash);
    std::istringstream fields(line);
    std::string word;
    while (fields >> word) words.push_back(word);
    if (words.size() > 4) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s line %u: '%s' after the OFF header's vertex, face and edge counts",
                          name, line_number, absl::CHexEscape(words[4].substr(0, 30))));
    }
    if (words.size() == 4) {
      return OffHeader{words[0] != "OFF", std::strtoull(words[1].c_str(), nullptr, 10)};
    }
  }
  return OffHeader{};
}

// Each face starts with its corner count, and OpenMesh reserves room for
// that many before reading them (it reads numbers, not lines), so a garbled
// count runs it out of memory (found by tests/fuzz). A face cannot have more
// corners than the file has vertices, and no number in the faces (counts,
// indices, colours) can be far above that.
absl::Status CheckOffFaceNumbers(std::ifstream& in, const std::string& name, size_t line_number,
                                 size_t nv) {
  const unsigned long long largest = std::max<unsigned long long>(nv, 1 << 20);
  std::string line;
  while (std::getline(in, line)) {
    ++line_number;
    if (auto hash = line.find('#'); hash != std::string::npos) line.resize(hash);
    std::istringstream fields(line);
    std::string word;
    for (bool first = true; fields >> word; first = false) {
      // Only numbers: OpenMesh reads numbers, not words, so "3-3" is two to
      // it, the second a corner count of about 2^32, and "-3" corners is
      // about 2^32 too (both found by fuzzing).
      char* end = nullptr;
      const double value = std::strtod(word.c_str(), &end);
      if (word.find_first_not_of("0123456789+-.eE") != std::string::npos ||
          end != word.c_str() + word.size()) {
        return absl::InvalidArgumentError(
            absl::StrFormat("%s line %u: '%s' in the faces is not a number", name, line_number,
                            absl::CHexEscape(word.substr(0, 30))));
      }
      const bool negative = value < 0;
      if (negative || value > largest || (first && value > nv)) {
        return absl::InvalidArgumentError(
            absl::StrFormat("%s line %u: %s%s%s, but the file has %u vertices", name, line_number,
                            first ? "a face with " : "the number ", word.substr(0, 30),
                            first ? " corners" : "", nv));
      }
    }
  }
  return absl::OkStatus();
}

// A variant's vertex lines are only counted (their positions are OpenMesh's
// to read), but its faces are checked all the same: a garbled corner count
// there ran OpenMesh out of memory too (found by fuzzing).
absl::StatusOr<AsciiVertices> ScanOffVertices(std::ifstream& in, const std::string& name) {
  AsciiVertices out;
  size_t line_number = 0;
  ASSIGN_OR_RETURN(const OffHeader header, ReadOffHeader(in, name, line_number));
  const size_t nv = header.vertices;
  size_t vertex_lines = 0;
  std::string line;
  while (vertex_lines < nv && std::getline(in, line)) {
    ++line_number;
    if (auto hash = line.find('#'); hash != std::string::npos) line.resize(hash);
    if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
    ++vertex_lines;
    if (header.variant) continue;
    absl::Status s = ParseAsciiVertex(line, name, line_number, out.positions);
    if (!s.ok()) return s;
  }
  // OpenMesh reads on past a short vertex list into the faces, garbage and
  // all, and looped there (found by fuzzing).
  if (vertex_lines < nv) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: the OFF header declares %u vertices, but %u vertex lines follow", name,
                        nv, vertex_lines));
  }
  out.available = !header.variant;
  RETURN_IF_ERROR(CheckOffFaceNumbers(in, name, line_number, nv));
  return out;
}

absl::StatusOr<AsciiVertices> ScanAsciiVertices(const std::string& path, const std::string& name,
                                                const std::string& format) {
  std::ifstream in(path);
  if (!in || (format != "obj" && format != "off")) return AsciiVertices{};
  return format == "obj" ? ScanObjVertices(in, name) : ScanOffVertices(in, name);
}

// Counts the file declares, where the format declares them.
struct DeclaredCounts {
  bool known = false;
  uint64_t vertices = 0, faces = 0;
};

DeclaredCounts ReadDeclaredCounts(const std::string& path, const std::string& format) {
  DeclaredCounts d;
  std::ifstream in(path, std::ios::binary);
  std::string line;
  if (format == "off") {
    std::string word;
    std::vector<uint64_t> numbers;
    bool keyword_seen = false;
    // Vertex, face and edge counts: OpenMesh reads all three, and one that
    // overflows its int fails the stream, after which it looped on faces
    // (found by fuzzing).
    while (numbers.size() < 3 && std::getline(in, line)) {
      auto hash = line.find('#');
      if (hash != std::string::npos) line.resize(hash);
      std::istringstream fields(line);
      while (numbers.size() < 3 && fields >> word) {
        // The keyword ([ST][C][N][4][n]OFF) comes first, once; a token that
        // merely contains "OFF" later is garbage that OpenMesh would read as
        // a count (found by tests/fuzz).
        if (!keyword_seen) {
          if (!IsOffKeyword(word)) return d;
          keyword_seen = true;
          continue;
        }
        // Digits only, to the token's end: a NUL inside the token would
        // stop strtoull early and pass garbage off as 0 (found by fuzzing:
        // OpenMesh then looped on faces it could not read).
        char* end;
        uint64_t v = std::strtoull(word.c_str(), &end, 10);
        if (!std::isdigit(static_cast<unsigned char>(word[0])) ||
            end != word.c_str() + word.size() || v > std::numeric_limits<int32_t>::max()) {
          return d;
        }
        numbers.push_back(v);
      }
    }
    if (numbers.size() == 3) d = {true, numbers[0], numbers[1]};
  } else if (format == "ply") {
    while (std::getline(in, line)) {
      if (!line.empty() && line.back() == '\r') line.pop_back();
      std::istringstream fields(line);
      std::string a, b;
      uint64_t n;
      fields >> a;
      if (a == "end_header") break;
      if (a == "element" && fields >> b >> n) {
        if (b == "vertex") d.vertices = n, d.known = true;
        if (b == "face") d.faces = n;
      }
    }
  }
  return d;
}

// OpenMesh 9.0's PLY reader loops forever on some malformed headers (found
// by tests/fuzz: a header line it does not know, before end_header). Only
// well-formed headers reach it.
absl::Status CheckPlyHeader(const std::string& path, const std::string& name) {
  std::ifstream in(path, std::ios::binary);
  std::string line;
  constexpr int kMaxHeaderLines = 100000;
  bool in_element = false;
  for (int number = 1; number <= kMaxHeaderLines && std::getline(in, line); ++number) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    // Words as OpenMesh's stream reads them; other control bytes (a form
    // feed inside "vertex" hung it, found by fuzzing) are not PLY.
    const bool plain = std::none_of(line.begin(), line.end(), [](char c) {
      return c != '\t' && std::iscntrl(static_cast<unsigned char>(c));
    });
    const std::vector<absl::string_view> f =
        absl::StrSplit(line, absl::ByAnyChar(" \t"), absl::SkipEmpty());
    const absl::string_view word = f.empty() ? "" : f[0];
    static const absl::flat_hash_set<absl::string_view> kTypes = {
        "char", "uchar", "short", "ushort", "int",   "uint",   "float",   "double",
        "int8", "uint8", "int16", "uint16", "int32", "uint32", "float32", "float64"};
    uint64_t count;
    bool ok = false;
    if (number == 1) {
      ok = line == "ply";
    } else if (number == 2) {
      // Version 1.0 is the only PLY there is; OpenMesh hangs on some others.
      ok = f.size() == 3 && word == "format" &&
           (f[1] == "ascii" || f[1] == "binary_little_endian" || f[1] == "binary_big_endian") &&
           f[2] == "1.0";
    } else if (word == "element") {
      ok = f.size() == 3 && absl::SimpleAtoi(f[2], &count);
      in_element = true;
    } else if (word == "property") {
      // OpenMesh crashes on a property before any element (found by fuzzing).
      ok = in_element &&
           ((f.size() == 3 && kTypes.contains(f[1])) ||
            (f.size() == 5 && f[1] == "list" && kTypes.contains(f[2]) && kTypes.contains(f[3])));
    } else {
      ok = word == "comment" || word == "obj_info" || (word == "end_header" && f.size() == 1);
    }
    if (!ok || !plain) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s: PLY header line %d is not a PLY header line: '%s'", name, number,
                          absl::CEscape(line.substr(0, 60))));
    }
    if (word == "end_header") return absl::OkStatus();
  }
  return absl::InvalidArgumentError(absl::StrFormat("%s: PLY header has no end_header line", name));
}

// Temporary mesh files are geodesic-mesh-<pid>-XXXXXX.<format>: the pid
// lets RemoveStaleTemporaryMeshFiles tell a dead process's file from a live
// one's.
constexpr std::string_view kTemporaryMeshPrefix = "geodesic-mesh-";

// OpenMesh's readers pick the format by file name: bytes read from memory, or
// rewritten, go through a private temporary file, which the caller removes
// right after reading.
absl::StatusOr<std::string> WriteTemporaryMeshFile(std::string_view bytes, const std::string& fmt) {
  std::string path = (std::filesystem::temp_directory_path() /
                      absl::StrFormat("%s%d-XXXXXX.%s", kTemporaryMeshPrefix, ::getpid(), fmt))
                         .string();
  int fd = ::mkstemps(path.data(), static_cast<int>(fmt.size() + 1));
  if (fd < 0) return absl::InternalError("cannot create a temporary file for the mesh");
  size_t written = 0;
  while (written < bytes.size()) {
    ssize_t n = ::write(fd, bytes.data() + written, bytes.size() - written);
    if (n <= 0) {
      ::close(fd);
      ::unlink(path.c_str());
      return absl::ResourceExhaustedError("cannot write the mesh to a temporary file");
    }
    written += n;
  }
  ::close(fd);
  return path;
}

// An OFF file's text without its comments ('#' to the end of a line) and
// blank lines, or nullopt when it has no comment. OpenMesh's OFF reader does
// not know comments: a comment line after the header made it read made-up
// counts (a different error on each run), and one among the vertices shifted
// every number after it, so the faces came out wrong and the file loaded all
// the same.
std::optional<std::string> OffWithoutComments(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (text.find('#') == std::string::npos) return std::nullopt;
  // Lines left blank go too: the keyword must open the text OpenMesh reads.
  std::string out;
  out.reserve(text.size());
  for (absl::string_view line : absl::StrSplit(text, '\n')) {
    line = line.substr(0, line.find('#'));
    if (line.find_first_not_of(" \t\r") == absl::string_view::npos) continue;
    out.append(line.data(), line.size());
    out.push_back('\n');
  }
  return out;
}

absl::StatusOr<TriangleSoup> ReadWithOpenMesh(const std::string& path, const std::string& name,
                                              const std::string& format,
                                              MeshDiagnostics* diagnostics) {
  SilenceOpenMesh();
  if (format == "ply") RETURN_IF_ERROR(CheckPlyHeader(path, name));
  const DeclaredCounts declared = ReadDeclaredCounts(path, format);
  // Refuse absurd declared counts before OpenMesh reserves memory for them.
  std::error_code ec;
  const uint64_t bytes = std::filesystem::file_size(path, ec);
  if (format == "off" && !declared.known) {
    // OpenMesh would make up counts from a garbled line (found by fuzzing:
    // it then reads vertices until memory runs out).
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: the OFF header's vertex and face counts are missing or not numbers", name));
  }
  if (declared.known && (declared.vertices > bytes || declared.faces > bytes)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s declares %u vertices and %u faces, more than its %u bytes can hold",
                        name, declared.vertices, declared.faces, bytes));
  }
  // Bad coordinates are reported by line before OpenMesh skips them.
  ASSIGN_OR_RETURN(AsciiVertices ascii, ScanAsciiVertices(path, name, format));
  TriangleSoup soup;
  SoupImporter importer(&soup);
  OpenMesh::IO::Options options;
  bool ok = false;
  // Read by name, never from a stream: OpenMesh's OFF reader learns a file's
  // variant from its header only when given the name, and a stream read
  // took the variant of the file read before.
  std::string uncommented;
  absl::Cleanup remove_uncommented = [&uncommented] {
    if (!uncommented.empty()) ::unlink(uncommented.c_str());
  };
  if (format == "off") {
    if (std::optional<std::string> text = OffWithoutComments(path)) {
      ASSIGN_OR_RETURN(uncommented, WriteTemporaryMeshFile(*text, format));
    }
  }
  try {
    ok =
        OpenMesh::IO::IOManager().read(uncommented.empty() ? path : uncommented, importer, options);
  } catch (const std::exception& e) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: unreadable %s file (%s)", name, format, e.what()));
  }
  if (!importer.first_error().empty()) {
    return absl::InvalidArgumentError(absl::StrFormat("%s: %s", name, importer.first_error()));
  }
  if (!ok) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: not a readable %s file (malformed or truncated)", name, format));
  }
  if (declared.known && (soup.positions.size() != declared.vertices ||
                         (format == "off" && importer.input_faces() != declared.faces) ||
                         (format == "ply" && importer.input_faces() != declared.faces))) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s is truncated or malformed: it declares %u vertices and %u faces but %u and %u were "
        "read",
        name, declared.vertices, declared.faces, soup.positions.size(), importer.input_faces()));
  }
  if (ascii.available) {
    if (ascii.positions.size() != soup.positions.size()) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s: %u vertex lines but %u vertices could be read", name,
                          ascii.positions.size(), soup.positions.size()));
    }
    soup.positions = std::move(ascii.positions);
  }
  if (diagnostics) diagnostics->polygons_triangulated = importer.polygons();
  return soup;
}

// What every reader's output must satisfy before diagnostics are computed
// on it: finite coordinates, and corners that name a vertex of the file
// (OpenMesh's importer checks those as it reads; GIFTI's arrays are
// checked here).
absl::Status CheckReadSoup(const TriangleSoup& soup, const std::string& name) {
  if (soup.positions.empty() && soup.triangles.empty()) {
    return absl::InvalidArgumentError(absl::StrFormat("%s: no vertices or faces", name));
  }
  for (size_t v = 0; v < soup.positions.size(); ++v) {
    const Vec3& p = soup.positions[v];
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s: vertex %u has a non-finite coordinate (%g, %g, %g)", name, v, p.x, p.y, p.z));
    }
  }
  for (size_t f = 0; f < soup.triangles.size(); ++f) {
    for (VertexId corner : soup.triangles[f]) {
      if (corner >= soup.positions.size()) {
        return absl::InvalidArgumentError(
            absl::StrFormat("%s: face %u refers to vertex %u, but the file has %u vertices", name,
                            f, corner, soup.positions.size()));
      }
    }
  }
  return absl::OkStatus();
}

// What a reader of `format` gave, checked, with diagnostics naming it.
absl::StatusOr<TriangleSoup> FinishRead(absl::StatusOr<TriangleSoup> soup, const std::string& name,
                                        const std::string& format, MeshDiagnostics* diagnostics) {
  if (!soup.ok()) return soup;
  RETURN_IF_ERROR(CheckReadSoup(*soup, name));
  if (diagnostics) {
    diagnostics->path = name;
    diagnostics->format = format;
  }
  return soup;
}

// Reads `path` (a file of `format`, named `name` in messages) with the
// reader of its format.
absl::StatusOr<TriangleSoup> ReadFormat(const std::string& path, const std::string& name,
                                        const std::string& format, MeshDiagnostics* diagnostics) {
  return FinishRead(format == "gii" ? ReadGiftiSurface(path, name)
                                    : ReadWithOpenMesh(path, name, format, diagnostics),
                    name, format, diagnostics);
}

// Whether `entry` is a temporary mesh file (WriteTemporaryMeshFile) whose
// process is gone, or one of the pid-less names it used before, older than
// `cutoff` (an hour: no read takes that long).
bool IsStaleTemporaryMeshFile(const std::filesystem::directory_entry& entry,
                              std::filesystem::file_time_type cutoff) {
  const std::string file = entry.path().filename().string();
  if (!file.starts_with(kTemporaryMeshPrefix)) return false;
  const absl::string_view rest = absl::string_view(file).substr(kTemporaryMeshPrefix.size());
  // mkstemps's six characters are letters and digits, never '-'.
  const size_t dash = rest.find('-');
  int pid = 0;
  if (dash != absl::string_view::npos && absl::SimpleAtoi(rest.substr(0, dash), &pid) && pid > 0) {
    return ::kill(pid, 0) != 0 && errno == ESRCH;
  }
  std::error_code ec;
  const auto written = entry.last_write_time(ec);
  return !ec && written < cutoff;
}

absl::Status CheckReadable(const std::string& path) {
  struct stat st;
  if (::stat(path.c_str(), &st) != 0) {
    if (errno == ENOENT) return absl::NotFoundError(absl::StrFormat("%s: no such file", path));
    return absl::PermissionDeniedError(
        absl::StrFormat("%s: cannot access (%s)", path, std::strerror(errno)));
  }
  if (S_ISDIR(st.st_mode)) {
    return absl::InvalidArgumentError(absl::StrFormat("%s is a directory", path));
  }
  if (::access(path.c_str(), R_OK) != 0) {
    return absl::PermissionDeniedError(absl::StrFormat("%s: permission denied", path));
  }
  if (st.st_size == 0) return absl::InvalidArgumentError(absl::StrFormat("%s is empty", path));
  return absl::OkStatus();
}

absl::Status CheckFormat(const std::string& format, std::string_view name) {
  if (IsMeshFormat(format)) return absl::OkStatus();
  return absl::InvalidArgumentError(absl::StrFormat("%s: unknown mesh format '%s' (supported: %s)",
                                                    name, format, MeshFormatList()));
}

}  // namespace

absl::Span<const std::string_view> MeshFormats() {
  static constexpr std::string_view kFormats[] = {"obj", "off", "ply", "stl", "gii"};
  return kFormats;
}

bool IsMeshFormat(std::string_view format) {
  return std::find(MeshFormats().begin(), MeshFormats().end(), format) != MeshFormats().end();
}

std::string MeshFormatList() {
  std::string list;
  for (std::string_view format : MeshFormats()) {
    if (!list.empty()) list += ", ";
    list += format;
  }
  return list;
}

std::string MeshFormatOfPath(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  if (!ext.empty()) ext.erase(0, 1);
  return absl::AsciiStrToLower(ext);
}

absl::StatusOr<TriangleSoup> ReadTriangleSoup(const std::string& path,
                                              MeshDiagnostics* diagnostics) {
  const auto start = std::chrono::steady_clock::now();
  RETURN_IF_ERROR(CheckReadable(path));
  const std::string format = MeshFormatOfPath(path);
  RETURN_IF_ERROR(CheckFormat(format, path));
  ASSIGN_OR_RETURN(TriangleSoup soup, ReadFormat(path, path, format, diagnostics));
  if (diagnostics) {
    diagnostics->load_seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  }
  return soup;
}

absl::StatusOr<TriangleSoup> ReadTriangleSoupFromMemory(std::string_view bytes,
                                                        std::string_view format,
                                                        std::string_view name,
                                                        MeshDiagnostics* diagnostics,
                                                        uint64_t max_decoded_bytes) {
  const std::string fmt = absl::AsciiStrToLower(std::string(format));
  RETURN_IF_ERROR(CheckFormat(fmt, name));
  if (bytes.empty()) return absl::InvalidArgumentError(absl::StrFormat("%s is empty", name));
  if (fmt == "gii") {
    return FinishRead(ReadGiftiSurfaceFromMemory(bytes, name, max_decoded_bytes), std::string(name),
                      fmt, diagnostics);
  }
  ASSIGN_OR_RETURN(const std::string path, WriteTemporaryMeshFile(bytes, fmt));
  auto soup = ReadFormat(path, std::string(name), fmt, diagnostics);
  ::unlink(path.c_str());
  return soup;
}

void RemoveStaleTemporaryMeshFiles() {
  std::error_code ec;
  const std::filesystem::path dir = std::filesystem::temp_directory_path(ec);
  if (ec) return;
  const auto an_hour_ago = std::filesystem::file_time_type::clock::now() - std::chrono::hours(1);
  // By error codes throughout: a file removed meanwhile is no reason to stop.
  std::filesystem::directory_iterator it(dir, ec), end;
  for (; !ec && it != end; it.increment(ec)) {
    std::error_code ignored;
    if (it->is_regular_file(ignored) && IsStaleTemporaryMeshFile(*it, an_hour_ago)) {
      std::filesystem::remove(it->path(), ignored);
    }
  }
}

absl::Status RequireFaces(const TriangleSoup& soup, std::string_view name) {
  if (!soup.triangles.empty()) return absl::OkStatus();
  return absl::InvalidArgumentError(
      absl::StrFormat("%s has no faces (%u vertices and no triangle): a mesh needs at least one",
                      name, soup.positions.size()));
}

absl::StatusOr<Mesh> LoadMesh(const std::string& path, const LoadOptions& options,
                              MeshDiagnostics* diagnostics) {
  MeshDiagnostics local;
  MeshDiagnostics& d = diagnostics ? *diagnostics : local;
  const auto start = std::chrono::steady_clock::now();
  ASSIGN_OR_RETURN(TriangleSoup soup, ReadTriangleSoup(path, &d));
  ComputeDiagnostics(soup, &d);
  if (absl::Status s = RequireFaces(soup, path); !s.ok()) {
    d.mesh_error = std::string(s.message());
    return s;
  }
  if (options.repair_non_manifold && !d.manifold) SplitNonManifoldVertices(&soup);
  auto mesh = Mesh::Build(std::move(soup), path);
  d.load_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (!mesh.ok()) {
    d.mesh_error = std::string(mesh.status().message());
    if (!options.repair_non_manifold && !d.manifold) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s (non-manifold input is rejected; pass --repair-non-manifold to split "
                          "non-manifold vertices)",
                          mesh.status().message()));
    }
  }
  return mesh;
}

}  // namespace geodesic
