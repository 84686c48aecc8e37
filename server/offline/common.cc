#include "server/offline/common.h"

#include <bit>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <utility>

#include "absl/status/status.h"
#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/base/status.h"
#include "core/mesh/mesh_io.h"
#include "core/mesh/surface_locator.h"
#include "core/query/result_files.h"

namespace geodesic::offline {

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
