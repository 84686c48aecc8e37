// libFuzzer target: the mesh readers on arbitrary bytes. The first byte
// picks the format; every input must give a mesh or a clear error, never a
// crash, a hang or unbounded memory.
#include <cstddef>
#include <cstdint>
#include <string_view>

#include "core/mesh/mesh.h"
#include "core/mesh/mesh_io.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size == 0) return 0;
  static constexpr const char* kFormats[] = {"obj", "off", "ply", "stl"};
  // GIFTI came later: first bytes from 0xf0 on pick it, which no input of
  // the corpus before it starts with, so those keep their formats.
  const char* format = data[0] >= 0xf0 ? "gii" : kFormats[data[0] % 4];
  std::string_view bytes(reinterpret_cast<const char*>(data + 1), size - 1);
  auto soup = geodesic::ReadTriangleSoupFromMemory(bytes, format, "fuzz");
  if (soup.ok()) {
    geodesic::MeshDiagnostics diagnostics;
    geodesic::ComputeDiagnostics(*soup, &diagnostics);
    (void)geodesic::Mesh::Build(*std::move(soup), "fuzz");
  }
  return 0;
}
