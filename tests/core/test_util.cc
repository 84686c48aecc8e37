#include "tests/core/test_util.h"

#include <stdlib.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <sstream>
#include <tuple>

namespace geodesic::testing {

std::string SharedPath(const std::string& relative) {
  const char* dir = getenv("GEODESIC_SHARED_DIR");
  return std::string(dir && *dir ? dir : GEODESIC_SHARED_DIR) + "/" + relative;
}

std::string SharedMeshPath(const std::string& name) {
  for (const char* ext : {".off", ".obj", ".ply", ".stl"}) {
    std::string path = SharedPath("meshes/" + name + ext);
    if (std::filesystem::exists(path)) return path;
  }
  return SharedPath("meshes/" + name);
}

bool SharedDataAvailable() {
  const std::string manifest = SharedPath("meshes/MANIFEST.md");
  if (std::filesystem::exists(manifest)) return true;
  ADD_FAILURE() << "shared data missing: " << manifest
                << " does not exist (clone the shared data beside the repository, or set "
                   "GEODESIC_SHARED_DIR)";
  return false;
}

std::string SourcePath(const std::string& relative) {
  return std::string(GEODESIC_SOURCE_DIR) + "/" + relative;
}

std::vector<double> ReadF64(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::vector<double> values;
  if (!in) return values;
  in.seekg(0, std::ios::end);
  values.resize(static_cast<size_t>(in.tellg()) / sizeof(double));
  in.seekg(0);
  in.read(reinterpret_cast<char*>(values.data()), values.size() * sizeof(double));
  return values;
}

std::string ReadBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream out;
  out << in.rdbuf();
  return out.str();
}

void WriteBytes(const std::string& path, const std::string& bytes) {
  std::ofstream(path, std::ios::binary | std::ios::trunc) << bytes;
}

TempDir::TempDir() {
  std::string pattern = (std::filesystem::temp_directory_path() / "geodesic-test-XXXXXX").string();
  char* made = mkdtemp(pattern.data());
  path_ = made ? made : "";
}

TempDir::~TempDir() {
  std::error_code ignored;
  if (!path_.empty()) std::filesystem::remove_all(path_, ignored);
}

Mesh MustBuild(TriangleSoup soup) {
  auto mesh = Mesh::Build(std::move(soup), "test mesh");
  EXPECT_TRUE(mesh.ok()) << mesh.status();
  return mesh.ok() ? std::move(mesh).value() : Mesh();
}

Mesh PlanarGrid(int nx, int ny, double h) {
  TriangleSoup soup;
  for (int j = 0; j <= ny; ++j)
    for (int i = 0; i <= nx; ++i) soup.positions.push_back({i * h, j * h, 0});
  auto id = [nx](int i, int j) { return static_cast<VertexId>(j * (nx + 1) + i); };
  for (int j = 0; j < ny; ++j) {
    for (int i = 0; i < nx; ++i) {
      // Alternate the diagonal so that the grid has no preferred direction.
      if ((i + j) % 2 == 0) {
        soup.triangles.push_back({id(i, j), id(i + 1, j), id(i + 1, j + 1)});
        soup.triangles.push_back({id(i, j), id(i + 1, j + 1), id(i, j + 1)});
      } else {
        soup.triangles.push_back({id(i, j), id(i + 1, j), id(i, j + 1)});
        soup.triangles.push_back({id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)});
      }
    }
  }
  return MustBuild(std::move(soup));
}

Mesh NoisyTorus(int nu, int nv, double stretch, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> jitter(-0.35, 0.35), radius(0.85, 1.15), coin(0, 1);
  TriangleSoup soup;
  constexpr double kTwoPi = 6.283185307179586;
  for (int i = 0; i < nu; ++i) {
    for (int j = 0; j < nv; ++j) {
      const double u = (i + jitter(rng)) * kTwoPi / nu, v = (j + jitter(rng)) * kTwoPi / nv;
      const double r = 0.35 * radius(rng);
      soup.positions.push_back({(1 + r * std::cos(v)) * std::cos(u),
                                stretch * (1 + r * std::cos(v)) * std::sin(u), r * std::sin(v)});
    }
  }
  auto id = [&](int i, int j) { return static_cast<VertexId>((i % nu) * nv + (j % nv)); };
  for (int i = 0; i < nu; ++i) {
    for (int j = 0; j < nv; ++j) {
      const VertexId a = id(i, j), b = id(i + 1, j), c = id(i + 1, j + 1), d = id(i, j + 1);
      if (coin(rng) < 0.5) {
        soup.triangles.push_back({a, b, d});
        soup.triangles.push_back({b, c, d});
      } else {
        soup.triangles.push_back({a, b, c});
        soup.triangles.push_back({a, c, d});
      }
    }
  }
  return MustBuild(std::move(soup));
}

Mesh Cube(int k) {
  // Six faces of [0,1]^3, each a (k+1)^2 grid; shared boundary vertices are
  // merged by coordinates so the cube is closed.
  TriangleSoup soup;
  std::map<std::tuple<long, long, long>, VertexId> index;
  auto vertex = [&](Vec3 p) {
    auto key = std::make_tuple(std::lround(p.x * k), std::lround(p.y * k), std::lround(p.z * k));
    auto [it, inserted] = index.emplace(key, static_cast<VertexId>(soup.positions.size()));
    if (inserted) soup.positions.push_back(p);
    return it->second;
  };
  // Each face: origin o, axes u, v, chosen so that u x v points outward.
  struct Side {
    Vec3 o, u, v;
  };
  const Side sides[6] = {
      {{0, 0, 0}, {0, 1, 0}, {1, 0, 0}}, {{0, 0, 1}, {1, 0, 0}, {0, 1, 0}},
      {{0, 0, 0}, {1, 0, 0}, {0, 0, 1}}, {{0, 1, 0}, {0, 0, 1}, {1, 0, 0}},
      {{0, 0, 0}, {0, 0, 1}, {0, 1, 0}}, {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}},
  };
  for (const Side& s : sides) {
    auto at = [&](int i, int j) {
      return vertex(s.o + s.u * (double(i) / k) + s.v * (double(j) / k));
    };
    for (int j = 0; j < k; ++j) {
      for (int i = 0; i < k; ++i) {
        VertexId a = at(i, j), b = at(i + 1, j), c = at(i + 1, j + 1), d = at(i, j + 1);
        soup.triangles.push_back({a, b, c});
        soup.triangles.push_back({a, c, d});
      }
    }
  }
  return MustBuild(std::move(soup));
}

}  // namespace geodesic::testing
