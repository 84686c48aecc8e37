// libFuzzer target: surface point specs (v:, e:, f:, xyz:) from users,
// parsed and, when they parse, validated against the bundled sample mesh.
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string_view>

#include "core/mesh/mesh_io.h"
#include "core/mesh/surface_point.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const auto* mesh = new geodesic::Mesh(*geodesic::LoadMesh(GEODESIC_SAMPLE_MESH));
  std::string_view text(reinterpret_cast<const char*>(data), size);
  auto spec = geodesic::ParseSurfacePointSpec(text);
  if (spec.ok() && !spec->is_position && geodesic::ValidateSurfacePoint(*mesh, spec->point).ok()) {
    (void)geodesic::PositionOf(*mesh, geodesic::CanonicalizeSurfacePoint(*mesh, spec->point));
  }
  return 0;
}
