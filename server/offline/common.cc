#include "server/offline/common.h"

#include <sys/resource.h>
#if defined(__GLIBC__)
#include <malloc.h>
#endif

#include <bit>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iterator>
#include <limits>
#include <utility>

#include "absl/status/status.h"
#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/strip.h"
#include "core/base/status.h"
#include "core/mesh/mesh_io.h"
#include "core/mesh/surface_locator.h"
#include "core/query/result_files.h"

namespace geodesic::offline {

void KeepFreedMemory() {
#if defined(__GLIBC__)
  // Allocations up to glibc's largest mmap threshold come from the heap,
  // where freed chunks are reused, and the heap's free top is never trimmed.
  mallopt(M_MMAP_THRESHOLD, 32 << 20);
  mallopt(M_TRIM_THRESHOLD, std::numeric_limits<int>::max());
#endif
}

int64_t MinorPageFaults() {
  struct rusage usage;
  return ::getrusage(RUSAGE_SELF, &usage) == 0 ? usage.ru_minflt : 0;
}

int Fail(const char* command, const absl::Status& status) {
  std::fprintf(stderr, "geodesicd %s: %s\n", command, std::string(status.message()).c_str());
  return 1;
}

absl::StatusOr<std::shared_ptr<const Mesh>> LoadMeshOrError(const std::string& path,
                                                            bool repair_non_manifold) {
  LoadOptions options;
  options.repair_non_manifold = repair_non_manifold;
  ASSIGN_OR_RETURN(Mesh mesh, LoadMesh(path, options));
  return std::make_shared<const Mesh>(std::move(mesh));
}

void AddRepairFlag(CLI::App& app, bool* repair) {
  app.add_flag("--repair-non-manifold", *repair,
               "split non-manifold vertices into one copy per fan (copies numbered after the "
               "file's vertices) instead of refusing the mesh");
}

absl::StatusOr<PointResolver::Resolved> PointResolver::Resolve(const std::string& spec) {
  ASSIGN_OR_RETURN(SurfacePointSpec parsed, ParseSurfacePointSpec(spec));
  Resolved r{parsed.point, std::nullopt};
  if (parsed.is_position) {
    if (!locator_) {
      ASSIGN_OR_RETURN(SurfaceLocator locator, SurfaceLocator::Build(mesh_));
      locator_.emplace(std::move(locator));
    }
    ASSIGN_OR_RETURN(r.point, locator_->Snap(parsed.position));
    r.snap_distance = Distance(parsed.position, PositionOf(mesh_, r.point));
  }
  absl::Status s = ValidateSurfacePoint(mesh_, r.point);
  if (!s.ok()) return absl::Status(s.code(), absl::StrFormat("%s: %s", spec, s.message()));
  return r;
}

namespace {

// The specs of a points file, each with its line number.
absl::StatusOr<std::vector<std::pair<size_t, std::string>>> ReadSpecLines(const std::string& path) {
  std::ifstream in(path);
  if (!in) return absl::NotFoundError(absl::StrFormat("cannot read %s", path));
  std::vector<std::pair<size_t, std::string>> specs;
  std::string line;
  for (size_t number = 1; std::getline(in, line); ++number) {
    const absl::string_view spec = absl::StripAsciiWhitespace(line);
    if (spec.empty() || spec.front() == '#') continue;
    specs.emplace_back(number, std::string(spec));
  }
  if (in.bad()) return absl::DataLossError(absl::StrFormat("error reading %s", path));
  return specs;
}

}  // namespace

absl::StatusOr<std::vector<SurfacePoint>> ResolvePointList(PointResolver& resolver,
                                                           const Mesh& mesh,
                                                           const std::vector<std::string>& args,
                                                           const std::string& flag) {
  std::vector<SurfacePoint> points;
  auto resolve = [&](const std::string& spec, const std::string& where) -> absl::Status {
    auto p = resolver.Resolve(spec);
    if (!p.ok()) return absl::Status(p.status().code(), absl::StrCat(where, p.status().message()));
    points.push_back(p->point);
    return absl::OkStatus();
  };
  for (const std::string& arg : args) {
    if (arg == "all") {
      for (VertexId v = 0; v < mesh.num_vertices(); ++v) points.push_back(SurfacePoint::Vertex(v));
    } else if (absl::StartsWith(arg, "@")) {
      const std::string path = arg.substr(1);
      ASSIGN_OR_RETURN(auto specs, ReadSpecLines(path));
      for (const auto& [line, spec] : specs) {
        RETURN_IF_ERROR(resolve(spec, absl::StrFormat("%s: %s line %u: ", flag, path, line)));
      }
    } else {
      RETURN_IF_ERROR(resolve(arg, flag + ": "));
    }
  }
  return points;
}

void AddRegionFlags(CLI::App& app, RegionFlags* flags, bool parent_ids) {
  auto* vertices = app.add_option(
      "--region-vertices", flags->vertices_path,
      "work on the region of the mesh these vertices span (the faces whose three vertices are "
      "all listed): a text file of vertex ids, one a line (# comments), or a .npy of ids or of "
      "one bool per vertex. Its vertices are numbered anew, in the mesh's order");
  app.add_option("--region-faces", flags->faces_path,
                 "as --region-vertices, but the region is these faces")
      ->excludes(vertices);
  if (parent_ids) {
    app.add_flag("--parent-ids", flags->parent_ids,
                 "with a region: points and outputs in the mesh file's vertex ids rather than "
                 "the region's (a point outside the region is refused; outputs hold +inf there, "
                 "as where unreached)");
  }
}

namespace {

// The integer or bool elements of a little-endian 1-d .npy.
absl::StatusOr<std::vector<uint32_t>> ReadNpyIds(const std::string& path, const std::string& flag) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrFormat("%s: cannot read %s", flag, path));
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  auto bad = [&](std::string_view why) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: %s is not a 1-d .npy of integer ids or bools: %s", flag, path, why));
  };
  if (bytes.size() < 10 || bytes.compare(0, 6, "\x93NUMPY") != 0) return bad("no NumPy header");
  // Version 1 has a 2-byte header length, later versions 4 bytes.
  const size_t length_bytes = bytes[6] == 1 ? 2 : 4;
  size_t header_length = 0;
  for (size_t i = 0; i < length_bytes; ++i) {
    header_length |= size_t(uint8_t(bytes[8 + i])) << (8 * i);
  }
  const size_t data_start = 8 + length_bytes + header_length;
  if (data_start > bytes.size()) return bad("truncated header");
  const std::string header = bytes.substr(8 + length_bytes, header_length);
  if (absl::StrContains(header, "'fortran_order': True")) return bad("Fortran order");
  const size_t descr = header.find("'descr': '");
  if (descr == std::string::npos) return bad("no descr");
  const std::string type = header.substr(descr + 10, 3);
  if (type.size() != 3) return bad("no descr");
  const char kind = type[1];
  const bool little = type[0] == '<' || type[0] == '|';
  const size_t width = type[2] - '0';
  if (!little || (kind != 'i' && kind != 'u' && kind != 'b') ||
      (width != 1 && width != 2 && width != 4 && width != 8)) {
    return bad(absl::StrCat("element type ", type));
  }
  const size_t shape = header.find("'shape': (");
  if (shape == std::string::npos) return bad("no shape");
  const std::string dims = header.substr(shape + 10, header.find(')', shape) - shape - 10);
  uint64_t count = 0;
  if (!absl::SimpleAtoi(absl::StripSuffix(absl::StripAsciiWhitespace(dims), ","), &count)) {
    return bad(absl::StrCat("shape (", dims, ")"));
  }
  if (data_start + count * width != bytes.size()) return bad("data size differs from its shape");
  std::vector<uint32_t> ids;
  for (uint64_t i = 0; i < count; ++i) {
    uint64_t raw = 0;
    std::memcpy(&raw, bytes.data() + data_start + i * width, width);
    const bool negative = kind == 'i' && width < 8 ? raw >> (8 * width - 1) : int64_t(raw) < 0;
    if (kind == 'b') {
      if (raw) ids.push_back(static_cast<uint32_t>(i));
    } else if ((kind == 'i' && negative) || raw >= kNone) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s: %s element %u is not a valid id", flag, path, i));
    } else {
      ids.push_back(static_cast<uint32_t>(raw));
    }
  }
  return ids;
}

}  // namespace

absl::StatusOr<std::vector<uint32_t>> ReadIdList(std::string path, const std::string& flag) {
  if (absl::StartsWith(path, "@")) path.erase(0, 1);
  if (absl::EndsWithIgnoreCase(path, ".npy")) return ReadNpyIds(path, flag);
  auto lines = ReadSpecLines(path);
  if (!lines.ok()) {
    return absl::Status(lines.status().code(), absl::StrCat(flag, ": ", lines.status().message()));
  }
  std::vector<uint32_t> ids;
  for (const auto& [line, text] : *lines) {
    uint32_t id = 0;
    if (!absl::SimpleAtoi(text, &id) || id == kNone) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s: %s line %u: '%s' is not an id", flag, path, line, text));
    }
    ids.push_back(id);
  }
  return ids;
}

void WorkMesh::AddJson(nlohmann::ordered_json& out) const {
  if (!region) return;
  out["region_vertices"] = region->mesh->num_vertices();
  out["region_faces"] = region->mesh->num_faces();
  out["parent_vertices"] = parent->num_vertices();
  out["parent_faces"] = parent->num_faces();
}

absl::StatusOr<WorkMesh> LoadWorkMesh(const std::string& path, bool repair,
                                      const RegionFlags& flags) {
  WorkMesh work;
  ASSIGN_OR_RETURN(work.parent, LoadMeshOrError(path, repair));
  if (!flags.given()) {
    if (flags.parent_ids) {
      return absl::InvalidArgumentError(
          "--parent-ids needs a region (--region-vertices or --region-faces)");
    }
    return work;
  }
  const bool by_vertex = !flags.vertices_path.empty();
  const std::string flag = by_vertex ? "--region-vertices" : "--region-faces";
  const std::string& mask_path = by_vertex ? flags.vertices_path : flags.faces_path;
  ASSIGN_OR_RETURN(std::vector<uint32_t> ids, ReadIdList(mask_path, flag));
  ASSIGN_OR_RETURN(
      Region region,
      ExtractRegion(*work.parent, by_vertex ? RegionMask::kVertices : RegionMask::kFaces, ids,
                    absl::StrCat(flag, " ", mask_path)));
  work.region = std::make_shared<const Region>(std::move(region));
  return work;
}

absl::StatusOr<SurfacePoint> IntoWorkMesh(const WorkMesh& work, const SurfacePoint& parent_point,
                                          const std::string& flag) {
  if (!work.region) return parent_point;
  auto mapped = PointInRegion(*work.parent, *work.region, parent_point);
  if (!mapped.ok()) {
    return absl::Status(mapped.status().code(),
                        absl::StrCat(flag, ": ", mapped.status().message()));
  }
  return mapped;
}

absl::StatusOr<WorkPoints> ResolveWorkPoints(const WorkMesh& work, bool parent_ids,
                                             PointResolver& resolver,
                                             const std::vector<std::string>& args,
                                             const std::string& flag) {
  WorkPoints out;
  if (!work.region || !parent_ids) {
    ASSIGN_OR_RETURN(out.points, ResolvePointList(resolver, *work.mesh(), args, flag));
    for (uint32_t i = 0; i < out.points.size(); ++i) out.slot.push_back(i);
    return out;
  }
  for (const std::string& arg : args) {
    if (arg == "all") {
      for (VertexId v : work.region->region_vertex) {
        out.slot.push_back(v == kNone ? kNone : static_cast<uint32_t>(out.points.size()));
        if (v != kNone) out.points.push_back(SurfacePoint::Vertex(v));
      }
      continue;
    }
    ASSIGN_OR_RETURN(std::vector<SurfacePoint> listed,
                     ResolvePointList(resolver, *work.parent, {arg}, flag));
    for (const SurfacePoint& p : listed) {
      ASSIGN_OR_RETURN(SurfacePoint mapped, IntoWorkMesh(work, p, flag));
      out.slot.push_back(static_cast<uint32_t>(out.points.size()));
      out.points.push_back(mapped);
    }
  }
  return out;
}

absl::StatusOr<SurfacePoint> ResolvePoint(const Mesh& mesh, const std::string& spec) {
  PointResolver resolver(mesh);
  ASSIGN_OR_RETURN(PointResolver::Resolved r, resolver.Resolve(spec));
  return r.point;
}

nlohmann::ordered_json SnapJson(const PointResolver::Resolved& r) {
  return r.snap_distance ? nlohmann::ordered_json(*r.snap_distance) : nlohmann::ordered_json();
}

absl::Status WriteFieldFile(const std::string& path, const std::vector<double>& values,
                            const Mesh& mesh) {
  TriangleSoup geometry;
  if (absl::EndsWithIgnoreCase(path, ".ply")) {
    geometry.positions = mesh.positions();
    for (FaceId f = 0; f < mesh.num_faces(); ++f) {
      geometry.triangles.push_back(
          {mesh.face_vertex(f, 0), mesh.face_vertex(f, 1), mesh.face_vertex(f, 2)});
    }
  }
  return WriteField(path, values, &geometry);
}

void PrintJson(const Json& value) { std::printf("%s\n", value.dump().c_str()); }

}  // namespace geodesic::offline
