// Accuracy on the bundled mesh (data/spot.obj) against truth computed here,
// at test time, by an independent exact solver: CGAL's
// Surface_mesh_shortest_path (Chen and Han's algorithm). These run on any
// clone; the shared meshes' precomputed truth adds larger and harder meshes
// when it is there (the *SharedMeshes* tests).
//
// Tolerances: our exact engine and CGAL's agree to rounding (both unfold in
// double precision), so to 1e-9 of the mesh's size. A graph's distances are
// never below the exact ones (edge weights round up) and the README's
// contract bounds them above by 1.5 epsilon (maximum) and 0.3 epsilon (mean).
#include <CGAL/Simple_cartesian.h>
#include <CGAL/Surface_mesh.h>
#include <CGAL/Surface_mesh_shortest_path.h>

#include <cmath>
#include <limits>
#include <memory>
#include <random>
#include <vector>

#include "core/exact/exact_geodesic.h"
#include "core/mesh/mesh_io.h"
#include "core/query/build_dgg.h"
#include "core/query/geodesic_engine.h"
#include "tests/core/test_util.h"

namespace geodesic {
namespace {

using Kernel = CGAL::Simple_cartesian<double>;
using CgalMesh = CGAL::Surface_mesh<Kernel::Point_3>;
using Traits = CGAL::Surface_mesh_shortest_path_traits<Kernel, CgalMesh>;
using ShortestPath = CGAL::Surface_mesh_shortest_path<Traits>;

constexpr double kExactTolerance = 1e-9;  // relative to the bounding box diagonal
constexpr double kContractMax = 1.5;      // epsilons
constexpr double kContractMean = 0.3;

// CGAL's copy of a triangle soup, with the same vertex and face ids.
std::unique_ptr<CgalMesh> CgalMeshOf(const TriangleSoup& soup) {
  auto cgal = std::make_unique<CgalMesh>();
  for (const Vec3& p : soup.positions) cgal->add_vertex(Kernel::Point_3(p.x, p.y, p.z));
  for (const auto& t : soup.triangles) {
    const auto face = cgal->add_face(CgalMesh::Vertex_index(t[0]), CgalMesh::Vertex_index(t[1]),
                                     CgalMesh::Vertex_index(t[2]));
    EXPECT_NE(face, CgalMesh::null_face());
  }
  EXPECT_EQ(cgal->number_of_faces(), soup.triangles.size());
  return cgal;
}

// CGAL's distances from a built tree's sources to every vertex, in id order.
std::vector<double> CgalVertexField(const CgalMesh& cgal, ShortestPath& tree) {
  std::vector<double> field;
  for (auto v : cgal.vertices()) field.push_back(tree.shortest_distance_to_source_points(v).first);
  return field;
}

// The largest absolute difference between two fields of the same size.
double WorstDifference(const std::vector<double>& a, const std::vector<double>& b) {
  double worst = 0;
  for (size_t v = 0; v < a.size(); ++v) worst = std::max(worst, std::abs(a[v] - b[v]));
  return worst;
}

// The bundled mesh, both as ours and as CGAL's, with the same vertex and face
// ids (the file's order).
class CgalTruth : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    auto soup = ReadTriangleSoup(testing::SourcePath("data/spot.obj"));
    ASSERT_OK(soup);
    auto mesh = LoadMesh(testing::SourcePath("data/spot.obj"));
    ASSERT_OK(mesh);
    mesh_ = std::make_shared<const Mesh>(std::move(mesh).value());
    cgal_ = CgalMeshOf(*soup).release();
    triangles_ = soup->triangles;
    ASSERT_EQ(cgal_->number_of_vertices(), mesh_->num_vertices());
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (const Vec3& p : soup->positions) {
      const double c[3] = {p.x, p.y, p.z};
      for (int k = 0; k < 3; ++k) lo[k] = std::min(lo[k], c[k]), hi[k] = std::max(hi[k], c[k]);
    }
    diagonal_ = std::hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]);
  }
  static void TearDownTestSuite() {
    delete cgal_;
    cgal_ = nullptr;
  }

  // CGAL's face location of our point: its barycentrics weight source,
  // target and next target of the face's halfedge, so ours (in the file's
  // corner order) are permuted to that order.
  static ShortestPath::Face_location Location(const SurfacePoint& p) {
    const CgalMesh::Face_index f(p.id);
    const auto h = cgal_->halfedge(f);
    const CgalMesh::Vertex_index corners[3] = {cgal_->source(h), cgal_->target(h),
                                               cgal_->target(cgal_->next(h))};
    // NaN until matched: a corner CGAL names that is not among the face's
    // would make every distance from this point NaN, and the test fail.
    const double unmatched = std::numeric_limits<double>::quiet_NaN();
    double b[3] = {unmatched, unmatched, unmatched};
    for (int k = 0; k < 3; ++k) {
      for (int j = 0; j < 3; ++j) {
        if (static_cast<uint32_t>(corners[k]) == triangles_[p.id][j]) b[k] = p.bary[j];
      }
    }
    return {f, {{b[0], b[1], b[2]}}};
  }

  static std::unique_ptr<ShortestPath> TreeFrom(const SurfacePoint& source) {
    auto tree = std::make_unique<ShortestPath>(*cgal_);
    if (source.kind == SurfacePoint::Kind::kVertex) {
      tree->add_source_point(CgalMesh::Vertex_index(source.id));
    } else {
      tree->add_source_point(Location(source));
    }
    tree->build_sequence_tree();
    return tree;
  }

  static std::vector<double> CgalField(const SurfacePoint& source) {
    return CgalVertexField(*cgal_, *TreeFrom(source));
  }

  static std::vector<SurfacePoint> Sources() {
    return {SurfacePoint::Vertex(0), SurfacePoint::Vertex(1500), SurfacePoint::Vertex(2929),
            SurfacePoint::Face(12, 0.2, 0.3, 0.5)};
  }

  static std::shared_ptr<const Mesh> mesh_;
  static CgalMesh* cgal_;
  static std::vector<std::array<uint32_t, 3>> triangles_;
  static double diagonal_;
};

std::shared_ptr<const Mesh> CgalTruth::mesh_;
CgalMesh* CgalTruth::cgal_ = nullptr;
std::vector<std::array<uint32_t, 3>> CgalTruth::triangles_;
double CgalTruth::diagonal_ = 0;

// Both sides must be real before they are compared.
void ExpectRealField(const std::vector<double>& field, size_t vertices, const char* who) {
  ASSERT_EQ(field.size(), vertices) << who;
  for (size_t v = 0; v < field.size(); ++v) {
    ASSERT_TRUE(std::isfinite(field[v]) && field[v] >= 0)
        << who << " vertex " << v << ": " << field[v];
  }
}

TEST_F(CgalTruth, ExactEngineEqualsCgal) {
  ExactGeodesic exact(*mesh_);
  for (const SurfacePoint& source : Sources()) {
    const std::vector<double> truth = CgalField(source);
    auto ours = exact.Distances(source);
    ASSERT_OK(ours);
    ExpectRealField(truth, mesh_->num_vertices(), "CGAL");
    ExpectRealField(*ours, mesh_->num_vertices(), "exact engine");
    EXPECT_LE(WorstDifference(*ours, truth), kExactTolerance * diagonal_)
        << FormatSurfacePoint(source);
  }
}

class CgalTruthAtEpsilon : public CgalTruth, public ::testing::WithParamInterface<double> {
 protected:
  static absl::StatusOr<std::shared_ptr<const DggGraph>> GraphAt(double eps) {
    DggBuildOptions options;
    options.params.epsilon = eps;
    return BuildDgg(*mesh_, options);
  }
};

TEST_P(CgalTruthAtEpsilon, GraphFieldsKeepTheContract) {
  const double eps = GetParam();
  auto graph = GraphAt(eps);
  ASSERT_OK(graph);
  GeodesicEngine engine(mesh_, *graph);
  for (const SurfacePoint& source : Sources()) {
    const std::vector<double> truth = CgalField(source);
    auto field = engine.Field({source}, {});
    ASSERT_OK(field);
    ExpectRealField(truth, mesh_->num_vertices(), "CGAL");
    ExpectRealField(field->distance, mesh_->num_vertices(), "graph");
    double worst = -INFINITY, sum = 0;
    size_t counted = 0;
    for (size_t v = 0; v < truth.size(); ++v) {
      // Where the exact distance is below the rounding of the positions, a
      // relative error means nothing: only that the graph is not below it.
      if (truth[v] <= kExactTolerance * diagonal_) {
        EXPECT_GE(field->distance[v], truth[v] - kExactTolerance * diagonal_);
        continue;
      }
      const double error = (field->distance[v] - truth[v]) / truth[v] / eps;
      EXPECT_GE(error * eps, -kExactTolerance) << "graph below exact at vertex " << v;
      worst = std::max(worst, error);
      sum += error;
      ++counted;
    }
    ASSERT_GT(counted, mesh_->num_vertices() / 2);
    EXPECT_LE(worst, kContractMax) << FormatSurfacePoint(source) << " at eps " << eps;
    EXPECT_LE(sum / counted, kContractMean) << FormatSurfacePoint(source) << " at eps " << eps;
  }
}

TEST_P(CgalTruthAtEpsilon, FacePointPairsKeepTheContract) {
  const double eps = GetParam();
  auto graph = GraphAt(eps);
  ASSERT_OK(graph);
  GeodesicEngine engine(mesh_, *graph);
  std::mt19937 rng(7);
  std::uniform_int_distribution<uint32_t> face(0, triangles_.size() - 1);
  std::uniform_real_distribution<double> unit(0.05, 1.0);
  auto random_point = [&] {
    const double a = unit(rng), b = unit(rng), c = unit(rng);
    return SurfacePoint::Face(face(rng), a / (a + b + c), b / (a + b + c), c / (a + b + c));
  };
  const int kPairs = 12;
  for (int i = 0; i < kPairs; ++i) {
    const SurfacePoint from = random_point(), to = random_point();
    const double truth =
        TreeFrom(from)
            ->shortest_distance_to_source_points(Location(to).first, Location(to).second)
            .first;
    PairOptions pair_options;
    pair_options.want_path = (i % 2 == 0);
    auto ours = engine.Distance(from, to, pair_options);
    ASSERT_OK(ours);
    ASSERT_TRUE(std::isfinite(truth) && truth > 0) << truth;
    ASSERT_TRUE(std::isfinite(ours->distance)) << ours->distance;
    const double error = (ours->distance - truth) / truth / eps;
    EXPECT_GE(error * eps, -kExactTolerance)
        << FormatSurfacePoint(from) << " -> " << FormatSurfacePoint(to);
    // The contract's bound holds for each pair; its mean is stated for
    // fields over every vertex, not for a dozen random face points.
    EXPECT_LE(error, kContractMax) << FormatSurfacePoint(from) << " -> " << FormatSurfacePoint(to);
  }
}

INSTANTIATE_TEST_SUITE_P(BundledMesh, CgalTruthAtEpsilon, ::testing::Values(1e-2, 1e-3));

// A hyperbolic paraboloid, z = (x^2 - y^2) / 2 on a grid, with a slit one
// cell wide cut through it: every interior vertex is a saddle, and what lies
// behind one, seen from the source, is reached through it; what lies behind
// the slit is reached around its ends, whose boundary corners turn by more
// than pi. Our vertices emit windows only in the directions a shortest path
// may leave them by (core/exact/exact_geodesic.cc, ExitDirections); CGAL's
// solver emits into every direction, so directions too narrow or turned the
// wrong way would show as longer distances behind the saddles or the slit.
TEST(CgalSaddleSurface, ExactEngineEqualsCgalThroughSaddlesAndAroundASlit) {
  constexpr int kSide = 24;
  TriangleSoup soup;
  for (int j = 0; j <= kSide; ++j) {
    for (int i = 0; i <= kSide; ++i) {
      const double x = 2.0 * i / kSide - 1, y = 2.0 * j / kSide - 1;
      soup.positions.push_back({x, y, (x * x - y * y) / 2});
    }
  }
  auto id = [](int i, int j) { return static_cast<VertexId>(j * (kSide + 1) + i); };
  // Cells (12, 6) to (12, 17) are left out: no vertex loses all its faces.
  auto in_slit = [](int i, int j) { return i == 12 && j >= 6 && j < 18; };
  for (int j = 0; j < kSide; ++j) {
    for (int i = 0; i < kSide; ++i) {
      if (in_slit(i, j)) continue;
      soup.triangles.push_back({id(i, j), id(i + 1, j), id(i + 1, j + 1)});
      soup.triangles.push_back({id(i, j), id(i + 1, j + 1), id(i, j + 1)});
    }
  }
  const std::unique_ptr<CgalMesh> cgal = CgalMeshOf(soup);
  auto mesh = Mesh::Build(soup, "saddle surface");
  ASSERT_OK(mesh);
  ExactGeodesic exact(*mesh);
  const double diagonal = 3;  // of the box [-1, 1]^2 x [-1/2, 1/2]
  for (const VertexId source : {id(0, kSide / 2), id(kSide / 2, 0), id(3, 5), id(9, 12)}) {
    ShortestPath tree(*cgal);
    tree.add_source_point(CgalMesh::Vertex_index(source));
    const std::vector<double> truth = CgalVertexField(*cgal, tree);
    auto ours = exact.Distances(SurfacePoint::Vertex(source));
    ASSERT_OK(ours);
    ExpectRealField(truth, mesh->num_vertices(), "CGAL");
    ExpectRealField(*ours, mesh->num_vertices(), "exact engine");
    EXPECT_LE(WorstDifference(*ours, truth), kExactTolerance * diagonal) << "source " << source;
    EXPECT_GT(exact.stats().pseudo_sources, 0u) << "source " << source;
    EXPECT_GT(exact.stats().pseudo_windows_skipped, 0u) << "source " << source;
  }
}

}  // namespace
}  // namespace geodesic
