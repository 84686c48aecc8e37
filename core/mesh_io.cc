#include "core/mesh_io.h"

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

#include "absl/container/flat_hash_map.h"
#include "absl/container/flat_hash_set.h"
#include "absl/status/status.h"
#include "absl/strings/ascii.h"
#include "absl/strings/escaping.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "core/status.h"

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

// The vertex count of an OFF header: header "OFF" (counts may follow on the
// same line), then the counts; '#' starts a comment. nullopt for a variant
// (COFF, NOFF, ...), whose values OpenMesh keeps; 0 if no count is found.
std::optional<size_t> ReadOffVertexCount(std::ifstream& in, size_t& line_number) {
  std::string line;
  std::vector<std::string> words;
  while (std::getline(in, line)) {
    ++line_number;
    if (auto hash = line.find('#'); hash != std::string::npos) line.resize(hash);
    std::istringstream fields(line);
    std::string word;
    while (fields >> word) words.push_back(word);
    if (!words.empty() && words[0] != "OFF") return std::nullopt;
    if (words.size() >= 2) return std::strtoull(words[1].c_str(), nullptr, 10);
  }
  return 0;
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

absl::StatusOr<AsciiVertices> ScanOffVertices(std::ifstream& in, const std::string& name) {
  AsciiVertices out;
  size_t line_number = 0;
  const std::optional<size_t> declared = ReadOffVertexCount(in, line_number);
  if (!declared) return out;
  const size_t nv = *declared;
  std::string line;
  while (out.positions.size() < nv && std::getline(in, line)) {
    ++line_number;
    if (auto hash = line.find('#'); hash != std::string::npos) line.resize(hash);
    if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
    absl::Status s = ParseAsciiVertex(line, name, line_number, out.positions);
    if (!s.ok()) return s;
  }
  // OpenMesh reads on past a short vertex list into the faces, garbage and
  // all, and looped there (found by fuzzing).
  if (out.positions.size() < nv) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: the OFF header declares %u vertices, but %u vertex lines follow", name,
                        nv, out.positions.size()));
  }
  out.available = true;
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
          if (word.size() > 6 || !word.ends_with("OFF")) return d;
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
  try {
    ok = OpenMesh::IO::IOManager().read(path, importer, options);
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
  if (soup.positions.empty() && soup.triangles.empty()) {
    return absl::InvalidArgumentError(absl::StrFormat("%s: no vertices or faces", name));
  }
  if (ascii.available) {
    if (ascii.positions.size() != soup.positions.size()) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s: %u vertex lines but %u vertices could be read", name,
                          ascii.positions.size(), soup.positions.size()));
    }
    soup.positions = std::move(ascii.positions);
  }
  for (size_t v = 0; v < soup.positions.size(); ++v) {
    const Vec3& p = soup.positions[v];
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s: vertex %u has a non-finite coordinate (%g, %g, %g)", name, v, p.x, p.y, p.z));
    }
  }
  if (diagnostics) {
    diagnostics->path = name;
    diagnostics->format = format;
    diagnostics->polygons_triangulated = importer.polygons();
  }
  return soup;
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
  if (format == "obj" || format == "off" || format == "ply" || format == "stl") {
    return absl::OkStatus();
  }
  return absl::InvalidArgumentError(absl::StrFormat(
      "%s: unknown mesh format '%s' (supported: obj, off, ply, stl)", name, format));
}

// Union-find over indices.
struct DisjointSets {
  std::vector<uint32_t> parent;
  explicit DisjointSets(size_t n) : parent(n) { std::iota(parent.begin(), parent.end(), 0); }
  uint32_t Find(uint32_t x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  }
  void Union(uint32_t a, uint32_t b) { parent[Find(a)] = Find(b); }
};

// The corner of face f at vertex v, as 3 * f + its position in the face.
uint32_t CornerOf(const TriangleSoup& soup, uint32_t f, VertexId v) {
  const auto& t = soup.triangles[f];
  return 3 * f + (t[0] == v ? 0 : t[1] == v ? 1 : 2);
}

// Every use of an edge by a face, as (UndirectedEdgeKey, corner 3 * face +
// k for the edge from corner k to k + 1), sorted so that the uses of one
// edge are adjacent. Degenerate edges (a face repeating a vertex) are left
// out. One linear pass over them then yields whatever is counted per edge.
EdgeUses SortedEdgeUses(const TriangleSoup& soup) {
  EdgeUses uses;
  uses.reserve(3 * soup.triangles.size());
  for (uint32_t f = 0; f < soup.triangles.size(); ++f) {
    const auto& t = soup.triangles[f];
    for (int k = 0; k < 3; ++k) {
      if (t[k] != t[(k + 1) % 3])
        uses.push_back({UndirectedEdgeKey(t[k], t[(k + 1) % 3]), 3 * f + k});
    }
  }
  SortEdgeUses(uses, soup.positions.size());
  return uses;
}

// Corners joined across every edge with exactly two faces, at both of its
// ends: the classes are the fans of faces around each vertex (one per
// vertex where the mesh is manifold).
DisjointSets CornerFans(const TriangleSoup& soup, const EdgeUses& uses) {
  DisjointSets fans(3 * soup.triangles.size());
  ForEachEdge(uses, [&](size_t i, size_t j) {
    if (j - i != 2) return;
    const VertexId a = uses[i].first >> 32, b = uses[i].first & 0xffffffffu;
    const uint32_t f0 = uses[i].second / 3, f1 = uses[i + 1].second / 3;
    fans.Union(CornerOf(soup, f0, a), CornerOf(soup, f1, a));
    fans.Union(CornerOf(soup, f0, b), CornerOf(soup, f1, b));
  });
  return fans;
}

}  // namespace

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
  ASSIGN_OR_RETURN(TriangleSoup soup, ReadWithOpenMesh(path, path, format, diagnostics));
  if (diagnostics) {
    diagnostics->load_seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  }
  return soup;
}

absl::StatusOr<TriangleSoup> ReadTriangleSoupFromMemory(std::string_view bytes,
                                                        std::string_view format,
                                                        std::string_view name,
                                                        MeshDiagnostics* diagnostics) {
  const std::string fmt = absl::AsciiStrToLower(std::string(format));
  RETURN_IF_ERROR(CheckFormat(fmt, name));
  if (bytes.empty()) return absl::InvalidArgumentError(absl::StrFormat("%s is empty", name));
  // OpenMesh's readers pick the format by file name: go through a private
  // temporary file that is removed right after reading.
  std::string pattern =
      (std::filesystem::temp_directory_path() / ("geodesic-upload-XXXXXX." + fmt)).string();
  int fd = ::mkstemps(pattern.data(), static_cast<int>(fmt.size() + 1));
  if (fd < 0) return absl::InternalError("cannot create a temporary file for the upload");
  size_t written = 0;
  while (written < bytes.size()) {
    ssize_t n = ::write(fd, bytes.data() + written, bytes.size() - written);
    if (n <= 0) {
      ::close(fd);
      ::unlink(pattern.c_str());
      return absl::ResourceExhaustedError("cannot write the upload to a temporary file");
    }
    written += n;
  }
  ::close(fd);
  auto soup = ReadWithOpenMesh(pattern, std::string(name), fmt, diagnostics);
  ::unlink(pattern.c_str());
  return soup;
}

namespace {

double BoundingBoxDiagonal(const std::vector<Vec3>& positions) {
  Vec3 lo{INFINITY, INFINITY, INFINITY}, hi{-INFINITY, -INFINITY, -INFINITY};
  for (const Vec3& p : positions) {
    lo = {std::min(lo.x, p.x), std::min(lo.y, p.y), std::min(lo.z, p.z)};
    hi = {std::max(hi.x, p.x), std::max(hi.y, p.y), std::max(hi.z, p.z)};
  }
  return positions.empty() ? 0 : Distance(lo, hi);
}

uint64_t CountDuplicateVertices(const std::vector<Vec3>& positions) {
  const size_t nv = positions.size();
  std::vector<uint32_t> order(nv);
  std::iota(order.begin(), order.end(), 0);
  auto key = [&](uint32_t i) {
    const Vec3& p = positions[i];
    return std::tie(p.x, p.y, p.z);
  };
  std::sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) { return key(a) < key(b); });
  uint64_t duplicates = 0;
  for (size_t i = 1; i < nv; ++i) duplicates += key(order[i]) == key(order[i - 1]);
  return duplicates;
}

// What one pass over the sorted edge uses finds.
struct EdgeCensus {
  std::vector<uint32_t> edge_of_corner;  // edge id of each corner's outgoing edge
  DisjointSets boundary_sets;            // vertices joined by boundary edges
  std::vector<uint8_t> on_boundary;
  double edge_sum = 0, edge_min = INFINITY;
  uint64_t edge_count = 0, twice_directed = 0, non_manifold_edges = 0;
};

// Edge counts, boundary and non-manifold edges and repeated directed edges
// from one pass over the sorted edge uses (hash maps keyed by edge took most
// of a load on million-face meshes).
EdgeCensus TakeEdgeCensus(const TriangleSoup& soup, const EdgeUses& uses) {
  const size_t nv = soup.positions.size(), nf = soup.triangles.size();
  EdgeCensus c{std::vector<uint32_t>(3 * nf, kNone), DisjointSets(nv), std::vector<uint8_t>(nv, 0)};
  auto from_of = [&](uint32_t corner) { return soup.triangles[corner / 3][corner % 3]; };
  ForEachEdge(uses, [&](size_t i, size_t j) {
    const VertexId a = uses[i].first >> 32, b = uses[i].first & 0xffffffffu;
    const double len = Distance(soup.positions[a], soup.positions[b]);
    c.edge_sum += len;
    c.edge_min = std::min(c.edge_min, len);
    int forward = 0;  // uses walking it from a (the smaller id) to b
    for (size_t u = i; u < j; ++u) {
      c.edge_of_corner[uses[u].second] = static_cast<uint32_t>(c.edge_count);
      forward += from_of(uses[u].second) == a;
    }
    ++c.edge_count;
    const size_t count = j - i;
    c.twice_directed += (forward > 1) + (static_cast<int>(count) - forward > 1);
    if (count > 2) ++c.non_manifold_edges;
    if (count == 1) {
      c.boundary_sets.Union(a, b);
      c.on_boundary[a] = c.on_boundary[b] = 1;
    }
  });
  return c;
}

// Zero-area and near-degenerate faces and the anisotropy of the others;
// needs d->bbox_diagonal for the area floor.
void MeasureFaceShapes(const TriangleSoup& soup, MeshDiagnostics* d) {
  std::vector<double> anisotropy;
  anisotropy.reserve(soup.triangles.size());
  d->zero_area_faces = d->near_degenerate_faces = 0;
  const double area_floor = 1e-12 * d->bbox_diagonal * d->bbox_diagonal;
  for (const auto& t : soup.triangles) {
    const Vec3 &a = soup.positions[t[0]], &b = soup.positions[t[1]], &c = soup.positions[t[2]];
    const double area = 0.5 * Norm(Cross(b - a, c - a));
    const bool repeated = t[0] == t[1] || t[1] == t[2] || t[0] == t[2];
    if (repeated || area <= area_floor) {
      ++d->zero_area_faces;
      continue;
    }
    const double la = Distance(b, c), lb = Distance(a, c), lc = Distance(a, b);
    const double inradius = 2 * area / (la + lb + lc);
    const double ratio = std::max({la, lb, lc}) / (2 * std::sqrt(3.0) * inradius);
    anisotropy.push_back(ratio);
    // Near-degenerate: so thin that angles lose most of their precision.
    if (ratio > 1e3) ++d->near_degenerate_faces;
  }
  if (!anisotropy.empty()) {
    d->anisotropy_mean =
        std::accumulate(anisotropy.begin(), anisotropy.end(), 0.0) / anisotropy.size();
    std::sort(anisotropy.begin(), anisotropy.end());
    d->anisotropy_p95 = anisotropy[static_cast<size_t>(0.95 * (anisotropy.size() - 1))];
    d->anisotropy_max = anisotropy.back();
  }
}

// Faces OpenMesh's kernel would refuse: the ones that make an edge carry a
// third face or repeat a directed edge, counted in file order.
uint64_t CountRefusedFaces(const TriangleSoup& soup, const EdgeCensus& edges) {
  // Per edge: bit 0 / 1 set once a kept face walks it from its smaller /
  // larger end, and how many kept faces it has (at most 2), times 4.
  std::vector<uint8_t> accepted(edges.edge_count, 0);
  uint64_t refused = 0;
  for (uint32_t f = 0; f < soup.triangles.size(); ++f) {
    const auto& t = soup.triangles[f];
    bool refuse = t[0] == t[1] || t[1] == t[2] || t[0] == t[2];
    for (int k = 0; k < 3 && !refuse; ++k) {
      const uint32_t e = edges.edge_of_corner[3 * f + k];
      const uint8_t direction = t[k] < t[(k + 1) % 3] ? 1 : 2;
      refuse = (accepted[e] & direction) || accepted[e] >= 8;
    }
    if (refuse) {
      ++refused;
      continue;
    }
    for (int k = 0; k < 3; ++k) {
      const uint32_t e = edges.edge_of_corner[3 * f + k];
      accepted[e] = (accepted[e] | (t[k] < t[(k + 1) % 3] ? 1 : 2)) + 4;
    }
  }
  return refused;
}

// How many sets of `sets` the vertices with member[v] set fall into.
uint64_t CountSetsAmong(DisjointSets& sets, const std::vector<uint8_t>& member) {
  std::vector<uint8_t> root_seen(member.size(), 0);
  uint64_t count = 0;
  for (size_t v = 0; v < member.size(); ++v) {
    if (!member[v]) continue;
    uint32_t r = sets.Find(v);
    if (!root_seen[r]) {
      root_seen[r] = 1;
      ++count;
    }
  }
  return count;
}

// Components of faces sharing a vertex.
uint64_t CountComponents(const TriangleSoup& soup, const std::vector<uint8_t>& used) {
  DisjointSets vertex_sets(soup.positions.size());
  for (const auto& t : soup.triangles) {
    vertex_sets.Union(t[0], t[1]);
    vertex_sets.Union(t[1], t[2]);
  }
  return CountSetsAmong(vertex_sets, used);
}

// The corners around a manifold vertex, joined across its two-face edges,
// form a single fan: count the vertices where they form more.
uint64_t CountNonManifoldVertices(const TriangleSoup& soup, DisjointSets& corners) {
  const size_t nv = soup.positions.size(), nf = soup.triangles.size();
  std::vector<uint32_t> first_root(nv, kNone);
  std::vector<uint8_t> pinched(nv, 0);
  for (uint32_t c = 0; c < 3 * nf; ++c) {
    VertexId v = soup.triangles[c / 3][c % 3];
    uint32_t r = corners.Find(c);
    if (first_root[v] == kNone) {
      first_root[v] = r;
    } else if (first_root[v] != r) {
      pinched[v] = 1;
    }
  }
  return std::count(pinched.begin(), pinched.end(), 1);
}

// Interior vertices whose angle sum exceeds 2 pi.
uint64_t CountSaddleVertices(const TriangleSoup& soup, const std::vector<uint8_t>& used,
                             const std::vector<uint8_t>& on_boundary) {
  const size_t nv = soup.positions.size();
  std::vector<double> angle_sum(nv, 0);
  for (const auto& t : soup.triangles) {
    for (int k = 0; k < 3; ++k) {
      const Vec3& p = soup.positions[t[k]];
      Vec3 u = soup.positions[t[(k + 1) % 3]] - p, w = soup.positions[t[(k + 2) % 3]] - p;
      double nu = Norm(u), nw = Norm(w);
      if (nu > 0 && nw > 0)
        angle_sum[t[k]] += std::acos(std::clamp(Dot(u, w) / (nu * nw), -1.0, 1.0));
    }
  }
  uint64_t saddles = 0;
  for (size_t v = 0; v < nv; ++v) {
    saddles += used[v] && !on_boundary[v] && angle_sum[v] > 2 * std::numbers::pi * (1 + 1e-10);
  }
  return saddles;
}

}  // namespace

void ComputeDiagnostics(const TriangleSoup& soup, MeshDiagnostics* d) {
  const size_t nv = soup.positions.size(), nf = soup.triangles.size();
  d->vertices = nv;
  d->faces = nf;
  d->bbox_diagonal = BoundingBoxDiagonal(soup.positions);
  d->duplicate_vertices = CountDuplicateVertices(soup.positions);
  const EdgeUses uses = SortedEdgeUses(soup);
  std::vector<uint8_t> used(nv, 0);
  for (const auto& t : soup.triangles) used[t[0]] = used[t[1]] = used[t[2]] = 1;
  EdgeCensus edges = TakeEdgeCensus(soup, uses);
  DisjointSets corners = CornerFans(soup, uses);
  MeasureFaceShapes(soup, d);
  d->non_manifold_edges = edges.non_manifold_edges;
  d->edges = edges.edge_count;
  d->mean_edge_length = edges.edge_count ? edges.edge_sum / edges.edge_count : 0;
  d->min_edge_length = edges.edge_count ? edges.edge_min : 0;
  d->isolated_vertices = std::count(used.begin(), used.end(), 0);
  d->faces_refused = CountRefusedFaces(soup, edges);
  d->components = CountComponents(soup, used);
  // Boundary loops: components of the graph of boundary edges.
  d->boundary_loops = CountSetsAmong(edges.boundary_sets, edges.on_boundary);
  d->boundary_vertices = std::count(edges.on_boundary.begin(), edges.on_boundary.end(), 1);
  d->non_manifold_vertices = CountNonManifoldVertices(soup, corners);
  d->manifold =
      d->non_manifold_edges == 0 && d->non_manifold_vertices == 0 && edges.twice_directed == 0;
  // Genus per the manifest: (2 * components - euler - boundary loops) / 2.
  const int64_t euler =
      int64_t(nv - d->isolated_vertices) - int64_t(edges.edge_count) + int64_t(nf);
  d->genus = (2 * int64_t(d->components) - euler - int64_t(d->boundary_loops)) / 2;
  d->saddle_vertices = CountSaddleVertices(soup, used, edges.on_boundary);
}

std::vector<VertexCopy> SplitNonManifoldVertices(TriangleSoup* soup) {
  const size_t nf = soup->triangles.size();
  DisjointSets corners = CornerFans(*soup, SortedEdgeUses(*soup));
  absl::flat_hash_map<uint64_t, VertexId> copy_of;  // (vertex, fan root) -> id
  std::vector<uint32_t> first_root(soup->positions.size(), kNone);
  std::vector<VertexCopy> copies;
  for (uint32_t c = 0; c < 3 * nf; ++c) {
    VertexId& v = soup->triangles[c / 3][c % 3];
    uint32_t r = corners.Find(c);
    if (first_root[v] == kNone) first_root[v] = r;
    if (first_root[v] == r) continue;
    auto [it, inserted] =
        copy_of.emplace((uint64_t{v} << 32) | r, static_cast<VertexId>(soup->positions.size()));
    if (inserted) {
      soup->positions.push_back(soup->positions[v]);
      copies.push_back({v, it->second});
    }
    v = it->second;
  }
  return copies;
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

std::string MeshDiagnostics::ToText() const {
  std::string s;
  s += absl::StrFormat("%s (%s)\n", path, format);
  s += absl::StrFormat("  vertices %u, faces %u, edges %u", vertices, faces, edges);
  if (polygons_triangulated)
    s += absl::StrFormat(" (%u polygons triangulated)", polygons_triangulated);
  s += absl::StrFormat("\n  components %u, boundary loops %u, genus %d%s\n", components,
                       boundary_loops, genus, manifold ? "" : " (not meaningful: non-manifold)");
  s += absl::StrFormat(
      "  isolated vertices %u, duplicate vertices %u, zero-area faces %u, near-degenerate "
      "faces %u\n",
      isolated_vertices, duplicate_vertices, zero_area_faces, near_degenerate_faces);
  s += absl::StrFormat(
      "  non-manifold edges %u, non-manifold vertices %u, faces OpenMesh would refuse %u\n",
      non_manifold_edges, non_manifold_vertices, faces_refused);
  s += absl::StrFormat("  bounding-box diagonal %.6g, edge length mean %.6g min %.6g\n",
                       bbox_diagonal, mean_edge_length, min_edge_length);
  s += absl::StrFormat("  anisotropy mean %.4g, p95 %.4g, max %.4g\n", anisotropy_mean,
                       anisotropy_p95, anisotropy_max);
  s += absl::StrFormat("  saddle vertices %u, boundary vertices %u\n", saddle_vertices,
                       boundary_vertices);
  s += absl::StrFormat("  loaded in %.3f s\n", load_seconds);
  s += mesh_error.empty() ? "  usable for geodesics: yes\n"
                          : absl::StrFormat("  usable for geodesics: no: %s\n", mesh_error);
  return s;
}

std::string MeshDiagnostics::ToJson() const {
  auto str = [](const std::string& x) {
    std::string out = "\"";
    for (char c : x) {
      if (c == '"' || c == '\\') out += '\\';
      if (static_cast<unsigned char>(c) < 0x20) {
        out += absl::StrFormat("\\u%04x", c);
        continue;
      }
      out += c;
    }
    return out + "\"";
  };
  return absl::StrFormat(
      "{\"path\": %s, \"format\": %s, \"vertices\": %u, \"faces\": %u, \"edges\": %u, "
      "\"polygons_triangulated\": %u, \"components\": %u, \"boundary_loops\": %u, \"genus\": %d, "
      "\"isolated_vertices\": %u, \"duplicate_vertices\": %u, \"zero_area_faces\": %u, "
      "\"near_degenerate_faces\": %u, \"non_manifold_edges\": %u, \"non_manifold_vertices\": %u, "
      "\"faces_refused\": %u, \"bbox_diagonal\": %.17g, \"mean_edge_length\": %.17g, "
      "\"min_edge_length\": %.17g, \"anisotropy_mean\": %.17g, \"anisotropy_p95\": %.17g, "
      "\"anisotropy_max\": %.17g, \"saddle_vertices\": %u, \"boundary_vertices\": %u, "
      "\"manifold\": %s, \"usable\": %s, \"mesh_error\": %s, \"load_seconds\": %.6f}",
      str(path), str(format), vertices, faces, edges, polygons_triangulated, components,
      boundary_loops, genus, isolated_vertices, duplicate_vertices, zero_area_faces,
      near_degenerate_faces, non_manifold_edges, non_manifold_vertices, faces_refused,
      bbox_diagonal, mean_edge_length, min_edge_length, anisotropy_mean, anisotropy_p95,
      anisotropy_max, saddle_vertices, boundary_vertices, manifold ? "true" : "false",
      mesh_error.empty() ? "true" : "false", str(mesh_error), load_seconds);
}

}  // namespace geodesic
