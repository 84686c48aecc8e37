// libFuzzer target: graph files as untrusted input. The bytes are written to
// a file and opened against the bundled sample mesh with the full check;
// a file that passes must then answer a query without faulting.
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <fstream>
#include <memory>
#include <string>

#include "core/dgg/graph_file.h"
#include "core/mesh/mesh_io.h"
#include "core/query/geodesic_engine.h"

namespace {

const std::shared_ptr<const geodesic::Mesh>& SampleMesh() {
  static const auto* mesh = new std::shared_ptr<const geodesic::Mesh>(
      std::make_shared<const geodesic::Mesh>(*geodesic::LoadMesh(GEODESIC_SAMPLE_MESH)));
  return *mesh;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const std::string path = "/tmp/graph_file_fuzzer." + std::to_string(getpid()) + ".dgg";
  std::ofstream(path, std::ios::binary | std::ios::trunc)
      .write(reinterpret_cast<const char*>(data), size);
  auto graph = geodesic::GraphFile::Open(path, *SampleMesh(), geodesic::GraphFile::Check::kFull);
  if (graph.ok()) {
    geodesic::GeodesicEngine engine(SampleMesh(), *graph);
    const auto source = geodesic::SurfacePoint::Vertex(0);
    (void)engine.Field({&source, 1}, {});
  }
  (void)geodesic::GraphFile::Inspect(path);
  return 0;
}
