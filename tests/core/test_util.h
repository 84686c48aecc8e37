// Shared helpers for core tests: paths to shared data, temp dirs, small meshes.
#ifndef GEODESIC_TESTS_CORE_TEST_UTIL_H_
#define GEODESIC_TESTS_CORE_TEST_UTIL_H_

#include <limits>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "core/mesh/mesh.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"

namespace geodesic::testing {

inline constexpr double kInf = std::numeric_limits<double>::infinity();

// ../shared next to the clone (meshes/, truth/); the environment variable
// GEODESIC_SHARED_DIR, when set, points elsewhere (to check what happens when
// it is missing without reconfiguring).
std::string SharedPath(const std::string& relative);
// Whether the shared data is there. When it is not, this also records a test
// failure naming the missing path: a test that needs shared data fails rather
// than skips (CI has it), even where the caller goes on to GTEST_SKIP.
bool SharedDataAvailable();
// The shared mesh called `name`, whatever its format.
std::string SharedMeshPath(const std::string& name);
std::string SourcePath(const std::string& relative);

// Reads a raw little-endian float64 file.
std::vector<double> ReadF64(const std::string& path);
// A whole file's bytes ("" when it cannot be read), and a file made of `bytes`.
std::string ReadBytes(const std::string& path);
void WriteBytes(const std::string& path, const std::string& bytes);

// A temporary directory removed when the object goes away.
class TempDir {
 public:
  TempDir();
  ~TempDir();
  const std::string& path() const { return path_; }
  std::string File(const std::string& name) const { return path_ + "/" + name; }

 private:
  std::string path_;
};

// Regular planar grid of nx x ny quads split into triangles, spacing h, z=0.
Mesh PlanarGrid(int nx, int ny, double h);
// Axis-aligned unit cube, each square face split into 2 * k * k triangles.
Mesh Cube(int k);
// A genus-1 surface made to stress exact propagation: a torus of nu x nv
// quads with jittered vertices and radii, one axis stretched by `stretch`,
// and each quad's diagonal chosen at random, so about half the vertices are
// saddles and many triangles are long and thin. Deterministic in `seed`.
Mesh NoisyTorus(int nu, int nv, double stretch, uint32_t seed);
// Mesh::Build that fails the test on error.
Mesh MustBuild(TriangleSoup soup);

inline const absl::Status& ToStatus(const absl::Status& s) { return s; }
template <typename T>
absl::Status ToStatus(const absl::StatusOr<T>& s) {
  return s.status();
}

}  // namespace geodesic::testing

#define EXPECT_OK(expr)                                                               \
  do {                                                                                \
    const ::absl::Status geodesic_test_status_ = ::geodesic::testing::ToStatus(expr); \
    EXPECT_TRUE(geodesic_test_status_.ok()) << geodesic_test_status_;                 \
  } while (0)
#define ASSERT_OK(expr)                                                               \
  do {                                                                                \
    const ::absl::Status geodesic_test_status_ = ::geodesic::testing::ToStatus(expr); \
    ASSERT_TRUE(geodesic_test_status_.ok()) << geodesic_test_status_;                 \
  } while (0)

#endif  // GEODESIC_TESTS_CORE_TEST_UTIL_H_
