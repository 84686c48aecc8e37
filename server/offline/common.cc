#include "server/offline/common.h"

#include <bit>
#include <cmath>
#include <cstdio>
#include <fstream>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "core/mesh_io.h"
#include "core/status.h"
#include "core/surface_locator.h"

namespace geodesic::offline {

int Fail(const char* command, const absl::Status& status) {
  std::fprintf(stderr, "geodesicd %s: %s\n", command, std::string(status.message()).c_str());
  return 1;
}

absl::StatusOr<std::shared_ptr<const Mesh>> LoadMeshOrError(const std::string& path) {
  ASSIGN_OR_RETURN(Mesh mesh, LoadMesh(path));
  return std::make_shared<const Mesh>(std::move(mesh));
}

absl::StatusOr<SurfacePoint> ResolvePoint(const Mesh& mesh, const std::string& spec) {
  ASSIGN_OR_RETURN(SurfacePointSpec parsed, ParseSurfacePointSpec(spec));
  SurfacePoint p = parsed.point;
  if (parsed.is_position) {
    ASSIGN_OR_RETURN(SurfaceLocator locator, SurfaceLocator::Build(mesh));
    ASSIGN_OR_RETURN(p, locator.Snap(parsed.position));
  }
  absl::Status s = ValidateSurfacePoint(mesh, p);
  if (!s.ok()) return absl::Status(s.code(), absl::StrFormat("%s: %s", spec, s.message()));
  return p;
}

absl::Status WriteF64(const std::string& path, const std::vector<double>& values) {
  static_assert(std::endian::native == std::endian::little, "f64 files are little-endian");
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) return absl::PermissionDeniedError(absl::StrFormat("cannot write %s", path));
  out.write(reinterpret_cast<const char*>(values.data()), values.size() * sizeof(double));
  if (!out) return absl::InternalError(absl::StrFormat("short write to %s", path));
  return absl::OkStatus();
}

void PrintJson(const Json& value) { std::printf("%s\n", value.dump().c_str()); }

}  // namespace geodesic::offline
