#include "core/exact/exact_geodesic.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <random>

#include "core/mesh/mesh_io.h"
#include "tests/core/test_util.h"

namespace geodesic {
namespace {

using testing::Cube;
using testing::PlanarGrid;
using testing::ReadF64;
using testing::SharedDataAvailable;
using testing::SharedPath;

using testing::kInf;

double RelativeError(double got, double want) {
  return std::abs(got - want) / std::max(std::abs(want), 1e-300);
}

TEST(ExactGeodesicTest, PlanarGridDistancesAreEuclidean) {
  Mesh grid = PlanarGrid(24, 20, 0.1);
  ExactGeodesic exact(grid);
  for (VertexId source : {VertexId{0}, VertexId{262}, VertexId{524}}) {
    auto d = exact.Distances(SurfacePoint::Vertex(source));
    ASSERT_OK(d);
    for (VertexId v = 0; v < grid.num_vertices(); ++v) {
      double want = Distance(grid.position(source), grid.position(v));
      if (v == source) {
        EXPECT_EQ((*d)[v], 0);
      } else {
        EXPECT_LT(RelativeError((*d)[v], want), 1e-12) << "source " << source << " vertex " << v;
      }
    }
  }
}

// A flat strip of long thin triangles (aspect 120, as CAD meshes have):
// geodesics along its grid lines run exactly along edges through collinear
// flat vertices, which windows reach only in the limit. Every distance must
// still be the straight line (before flat vertices radiated, whole lines of
// vertices beyond such a run were unreached or long; blade_aniso).
TEST(ExactGeodesicTest, ThinFlatStripAlongCollinearVertices) {
  TriangleSoup soup;
  const int nx = 60, ny = 4;
  const double hx = 1.868, hy = 0.0155;
  for (int j = 0; j <= ny; ++j) {
    for (int i = 0; i <= nx; ++i) soup.positions.push_back({i * hx, j * hy, 0});
  }
  auto id = [&](int i, int j) { return static_cast<VertexId>(j * (nx + 1) + i); };
  for (int j = 0; j < ny; ++j) {
    for (int i = 0; i < nx; ++i) {
      soup.triangles.push_back({id(i, j), id(i + 1, j), id(i + 1, j + 1)});
      soup.triangles.push_back({id(i, j), id(i + 1, j + 1), id(i, j + 1)});
    }
  }
  Mesh strip = testing::MustBuild(std::move(soup));
  ExactGeodesic exact(strip);
  for (VertexId source : {id(0, 2), id(0, 0), id(30, 2), id(5, 1)}) {
    auto d = exact.Distances(SurfacePoint::Vertex(source));
    ASSERT_OK(d);
    for (VertexId v = 0; v < strip.num_vertices(); ++v) {
      const double want = Distance(strip.position(source), strip.position(v));
      if (v == source) continue;
      EXPECT_LT(RelativeError((*d)[v], want), 1e-10) << "source " << source << " vertex " << v;
    }
  }
}

TEST(ExactGeodesicTest, PlanarGridFromFaceAndEdgePoints) {
  Mesh grid = PlanarGrid(16, 16, 0.25);
  ExactGeodesic exact(grid);
  const SurfacePoint sources[] = {SurfacePoint::Face(100, 0.2, 0.3, 0.5),
                                  SurfacePoint::Face(7, 0.6, 0.2, 0.2),
                                  SurfacePoint::Edge(200, 0.37)};
  for (const SurfacePoint& s : sources) {
    auto d = exact.Distances(s);
    ASSERT_OK(d);
    Vec3 p = PositionOf(grid, s);
    for (VertexId v = 0; v < grid.num_vertices(); ++v) {
      EXPECT_LT(RelativeError((*d)[v], Distance(p, grid.position(v))), 1e-12) << "vertex " << v;
    }
  }
}

// Shortest route from the bottom-face centre of the unit cube to a vertex:
// in the bottom face straight; on a side face through the bottom edge it
// shares; on the top face through the best of the four sides.
double CubeDistanceFromBottomCentre(const Vec3& p) {
  const double eps = 1e-12;
  if (p.z < eps) return std::hypot(p.x - 0.5, p.y - 0.5);
  auto side = [&](double along, double out) { return std::hypot(along - 0.5, 0.5 + out); };
  if (p.z > 1 - eps) {
    return std::min({side(p.y, 1 + (1 - p.x)), side(p.y, 1 + p.x), side(p.x, 1 + (1 - p.y)),
                     side(p.x, 1 + p.y)});
  }
  if (p.x > 1 - eps) return side(p.y, p.z);
  if (p.x < eps) return side(p.y, p.z);
  if (p.y > 1 - eps) return side(p.x, p.z);
  return side(p.x, p.z);
}

TEST(ExactGeodesicTest, CubeMatchesUnfoldings) {
  Mesh cube = Cube(6);
  VertexId centre = kNone;
  for (VertexId v = 0; v < cube.num_vertices(); ++v) {
    if (Distance(cube.position(v), {0.5, 0.5, 0}) < 1e-12) centre = v;
  }
  ASSERT_NE(centre, kNone);
  ExactGeodesic exact(cube);
  auto d = exact.Distances(SurfacePoint::Vertex(centre));
  ASSERT_OK(d);
  for (VertexId v = 0; v < cube.num_vertices(); ++v) {
    if (v == centre) continue;
    EXPECT_LT(RelativeError((*d)[v], CubeDistanceFromBottomCentre(cube.position(v))), 1e-12)
        << "vertex at " << cube.position(v).x << "," << cube.position(v).y << ","
        << cube.position(v).z;
  }
}

TEST(ExactGeodesicTest, CubeCornerToOppositeCorner) {
  Mesh cube = Cube(4);
  VertexId a = kNone, b = kNone;
  for (VertexId v = 0; v < cube.num_vertices(); ++v) {
    if (Distance(cube.position(v), {0, 0, 0}) == 0) a = v;
    if (Distance(cube.position(v), {1, 1, 1}) == 0) b = v;
  }
  ExactGeodesic exact(cube);
  auto d = exact.Distances(SurfacePoint::Vertex(a));
  ASSERT_OK(d);
  EXPECT_LT(RelativeError((*d)[b], std::sqrt(5.0)), 1e-12);
}

TEST(ExactGeodesicTest, DisconnectedPartsAreInfinite) {
  TriangleSoup soup;
  soup.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {5, 0, 0}, {6, 0, 0}, {5, 1, 0}, {9, 9, 9}};
  soup.triangles = {{0, 1, 2}, {3, 4, 5}};
  Mesh mesh = testing::MustBuild(soup);
  ExactGeodesic exact(mesh);
  auto d = exact.Distances(SurfacePoint::Vertex(0));
  ASSERT_OK(d);
  EXPECT_EQ((*d)[0], 0);
  EXPECT_DOUBLE_EQ((*d)[1], 1);
  EXPECT_EQ((*d)[3], kInf);
  EXPECT_EQ((*d)[6], kInf);  // isolated vertex
}

TEST(ExactGeodesicTest, RejectsBadSources) {
  Mesh grid = PlanarGrid(4, 4, 1);
  ExactGeodesic exact(grid);
  EXPECT_EQ(exact.Distances(SurfacePoint::Vertex(1000)).status().code(),
            absl::StatusCode::kOutOfRange);
  EXPECT_EQ(exact.Distances(SurfacePoint::Face(0, 0.5, 0.5, 0.5)).status().code(),
            absl::StatusCode::kInvalidArgument);
}

TEST(ExactGeodesicTest, DistanceLimitAndTargets) {
  Mesh grid = PlanarGrid(30, 30, 0.1);
  ExactGeodesic exact(grid);
  ExactOptions limited;
  limited.max_distance = 1.0;
  auto d = exact.Distances(SurfacePoint::Vertex(480), limited);
  ASSERT_OK(d);
  for (VertexId v = 0; v < grid.num_vertices(); ++v) {
    double want = Distance(grid.position(480), grid.position(v));
    if (want <= 0.999) {
      EXPECT_LT(RelativeError((*d)[v], want), 1e-12);
    } else if (want > 1.001) {
      EXPECT_EQ((*d)[v], kInf);
    }
  }
  ASSERT_OK(exact.Distances(SurfacePoint::Vertex(480)));
  const uint64_t full_work = exact.stats().windows_propagated;
  ExactOptions targeted;
  targeted.targets = {481, 511};
  auto t = exact.Distances(SurfacePoint::Vertex(480), targeted);
  ASSERT_OK(t);
  EXPECT_LT(RelativeError((*t)[511], Distance(grid.position(480), grid.position(511))), 1e-12);
  // Near targets stop the sweep early.
  EXPECT_LT(exact.stats().windows_propagated, full_work / 4);
}

// The bounds a goal run drops windows by are the least route over the
// window's segment, not the sum of two minima taken at different points
// (which let a third more windows through with a perfect goal floor,
// bench/measurements.md, "Exact pairs"): never above a dense sampling of
// the route, and within the sampling's step of its least value.
TEST(ExactGeodesicTest, GoalBoundsAreTheLeastRouteOverTheSegment) {
  using exact_internal::FlooredRest;
  using exact_internal::LeastFlooredRoute;
  using exact_internal::LeastStraightRoute;
  using exact_internal::SegmentRoutes;
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(0, 1);
  int looser_sum = 0;
  for (int trial = 0; trial < 2000; ++trial) {
    const double length = 0.5 + u(rng);
    double b0 = length * u(rng), b1 = length * u(rng);
    if (b0 > b1) std::swap(b0, b1);
    const SegmentRoutes r{{3 * u(rng) - 1, -0.01 - 2 * u(rng)}, u(rng), b0, b1};
    const Vec2 goal{4 * u(rng) - 2, 2 * u(rng) - 1};
    const double f_tail = 3 * u(rng), f_head = 3 * u(rng);
    auto at = [&](double x) { return r.sigma + std::hypot(x - r.s.x, r.s.y); };
    double straight = kInf, floored = kInf, nearest = kInf, to_goal = kInf;
    for (int k = 0; k <= 20000; ++k) {
      const double x = b0 + (b1 - b0) * k / 20000;
      const double goal_line = std::hypot(goal.x - x, goal.y);
      straight = std::min(straight, at(x) + goal_line);
      floored = std::min(floored, at(x) + std::max(f_tail - x, f_head - (length - x)));
      nearest = std::min(nearest, at(x));
      to_goal = std::min(to_goal, goal_line);
    }
    ASSERT_TRUE(std::isfinite(straight) && std::isfinite(floored));
    const double got_straight = LeastStraightRoute(r, goal);
    const double got_floored = LeastFlooredRoute(r, FlooredRest(r, length, f_tail, f_head));
    EXPECT_LE(got_straight, straight + 1e-12) << trial;
    // Samples miss the least value by at most a step times the slope
    // (under 2) on either side.
    const double sampling = 2 * (b1 - b0) / 20000;
    EXPECT_GE(got_straight, straight - sampling) << trial;
    EXPECT_LE(got_floored, floored + 1e-12) << trial;
    EXPECT_GE(got_floored, floored - sampling) << trial;
    if (nearest + to_goal < straight - 1e-3) ++looser_sum;
  }
  // The separate minima are often far looser: the cases are not degenerate.
  EXPECT_GT(looser_sum, 200);
}

class TruthTest : public ::testing::TestWithParam<std::string> {};

// Against the independent exact solver's fields (../shared/truth).
TEST_P(TruthTest, MatchesExactFields) {
  ASSERT_TRUE(SharedDataAvailable());
  const std::string name = GetParam();
  auto mesh = LoadMesh(testing::SharedMeshPath(name));
  ASSERT_OK(mesh);
  ExactGeodesic exact(*mesh);
  const VertexId n = mesh->num_vertices();
  for (VertexId source : {VertexId{0}, n / 3, 2 * n / 3}) {
    auto truth =
        ReadF64(SharedPath("truth/" + name + ".exact.s" + std::to_string(source) + ".f64"));
    ASSERT_EQ(truth.size(), n);
    auto d = exact.Distances(SurfacePoint::Vertex(source));
    ASSERT_OK(d);
    double sum = 0, worst = 0;
    size_t count = 0;
    for (VertexId v = 0; v < n; ++v) {
      if (std::isnan(truth[v])) {
        EXPECT_EQ((*d)[v], kInf) << "vertex " << v;
        continue;
      }
      if (truth[v] == 0) continue;
      double e = RelativeError((*d)[v], truth[v]);
      sum += e;
      worst = std::max(worst, e);
      ++count;
    }
    EXPECT_LT(sum / count, 1e-9) << name << " source " << source;
    EXPECT_LT(worst, 1e-6) << name << " source " << source;
  }
}

INSTANTIATE_TEST_SUITE_P(SharedMeshes, TruthTest,
                         ::testing::Values("eight", "spot", "blade_aniso", "camelhead", "fertility",
                                           "bunny", "armadillo"));

class SpotTest : public ::testing::Test {
 protected:
  void SetUp() override {
    auto mesh = LoadMesh(testing::SourcePath("data/spot.obj"));
    ASSERT_OK(mesh);
    mesh_ = std::make_unique<Mesh>(std::move(mesh).value());
  }
  std::unique_ptr<Mesh> mesh_;
};

TEST_F(SpotTest, SymmetricAndTriangleInequality) {
  ExactGeodesic exact(*mesh_);
  std::mt19937 rng(7);
  std::uniform_int_distribution<VertexId> pick(0, mesh_->num_vertices() - 1);
  for (int trial = 0; trial < 6; ++trial) {
    VertexId a = pick(rng), b = pick(rng), c = pick(rng);
    auto da = exact.Distances(SurfacePoint::Vertex(a));
    auto db = exact.Distances(SurfacePoint::Vertex(b));
    ASSERT_OK(da);
    ASSERT_OK(db);
    EXPECT_LT(std::abs((*da)[b] - (*db)[a]), 1e-12 * (*da)[b] + 1e-15);
    EXPECT_LE((*da)[c], (*da)[b] + (*db)[c] + 1e-12);
  }
}

TEST_F(SpotTest, DirectGeodesicsNeverUndercutExact) {
  ExactGeodesic exact(*mesh_);
  for (VertexId s : {VertexId{10}, VertexId{1500}, VertexId{2900}}) {
    auto full = exact.Distances(SurfacePoint::Vertex(s));
    ASSERT_OK(full);
    DirectOptions options;
    options.epsilon = 1e-3;
    auto hits = exact.DirectGeodesics(SurfacePoint::Vertex(s), options);
    ASSERT_OK(hits);
    EXPECT_GT(hits->size(), 20u);
    size_t exact_hits = 0;
    for (const DirectHit& h : *hits) {
      EXPECT_GE(h.distance, (*full)[h.vertex] * (1 - 1e-12)) << "vertex " << h.vertex;
      EXPECT_GE(h.angle_at_source, 0);
      EXPECT_LT(h.angle_at_source, mesh_->total_angle(s) + 1e-12);
      EXPECT_GE(h.angle_at_vertex, 0);
      EXPECT_LT(h.angle_at_vertex, mesh_->total_angle(h.vertex) + 1e-12);
      if (RelativeError(h.distance, (*full)[h.vertex]) < 1e-12) ++exact_hits;
    }
    // Near the source almost every direct geodesic is the shortest one.
    EXPECT_GT(exact_hits, hits->size() / 2);
  }
}

TEST_F(SpotTest, SharedFaceFramesChangeNoResult) {
  const FaceFrames frames(*mesh_);
  ExactGeodesic plain(*mesh_), shared(*mesh_, &frames);
  DirectOptions options;
  options.epsilon = 1e-3;
  for (VertexId s : {VertexId{10}, VertexId{1500}, VertexId{2900}}) {
    auto a = plain.DirectGeodesics(SurfacePoint::Vertex(s), options);
    auto b = shared.DirectGeodesics(SurfacePoint::Vertex(s), options);
    ASSERT_OK(a);
    ASSERT_OK(b);
    ASSERT_EQ(a->size(), b->size());
    for (size_t i = 0; i < a->size(); ++i) {
      EXPECT_EQ((*a)[i].vertex, (*b)[i].vertex);
      EXPECT_EQ((*a)[i].distance, (*b)[i].distance) << "vertex " << (*a)[i].vertex;
      EXPECT_EQ((*a)[i].angle_at_source, (*b)[i].angle_at_source);
    }
    auto full_a = plain.Distances(SurfacePoint::Vertex(s));
    auto full_b = shared.Distances(SurfacePoint::Vertex(s));
    ASSERT_OK(full_a);
    ASSERT_OK(full_b);
    EXPECT_EQ(*full_a, *full_b);
  }
}

// children_computed counts what VTP counts as interval propagations: every
// child made by propagating a window across a face, before any trim. A
// window makes at most two children, and every queued window is such a child
// or was emitted across a face of the source's or a pseudo-source's fan.
TEST_F(SpotTest, StatsCountEveryChildBeforeItsTrim) {
  std::vector<uint64_t> fan(mesh_->num_vertices(), 0);
  for (HalfedgeId h = 0; h < mesh_->num_halfedges(); ++h) ++fan[mesh_->tail(h)];
  const uint64_t largest_fan = *std::max_element(fan.begin(), fan.end());
  ExactGeodesic exact(*mesh_);
  ASSERT_OK(exact.Distances(SurfacePoint::Vertex(10)));
  const ExactStats& st = exact.stats();
  ASSERT_GT(st.windows_propagated, 1000u);
  EXPECT_GT(st.children_computed, st.windows_propagated / 2);
  EXPECT_LE(st.children_computed, 2 * st.windows_propagated);
  EXPECT_LE(st.windows_created, st.children_computed + (st.pseudo_sources + 1) * largest_fan);
}

TEST_F(SpotTest, DirectAnglesOfMeshEdgesMatchTheFrame) {
  ExactGeodesic exact(*mesh_);
  const VertexId s = 100;
  auto hits = exact.DirectGeodesics(SurfacePoint::Vertex(s), {});
  ASSERT_OK(hits);
  HalfedgeId h = mesh_->vertex_halfedge(s);
  const HalfedgeId start = h;
  do {
    VertexId u = mesh_->head(h);
    auto it =
        std::find_if(hits->begin(), hits->end(), [&](const DirectHit& x) { return x.vertex == u; });
    ASSERT_NE(it, hits->end());
    EXPECT_NEAR(it->angle_at_source, mesh_->polar_angle(h), 1e-9);
    EXPECT_NEAR(it->angle_at_vertex, mesh_->polar_angle(mesh_->twin(h)), 1e-9);
    h = mesh_->rotate(h);
  } while (h != kNone && h != start);
}

double PathLength(const std::vector<ExactGeodesic::TracePoint>& path) {
  double length = 0;
  for (size_t i = 1; i < path.size(); ++i) length += Distance(path[i - 1].xyz, path[i].xyz);
  return length;
}

TEST_F(SpotTest, TracedPathsHaveTheDistanceAsLength) {
  ExactGeodesic exact(*mesh_);
  ExactOptions options;
  options.keep_windows = true;
  auto d = exact.Distances(SurfacePoint::Vertex(5), options);
  ASSERT_OK(d);
  std::mt19937 rng(3);
  std::uniform_int_distribution<VertexId> pick(0, mesh_->num_vertices() - 1);
  for (int i = 0; i < 40; ++i) {
    VertexId t = pick(rng);
    auto path = exact.Trace(SurfacePoint::Vertex(t));
    ASSERT_OK(path);
    ASSERT_GE(path->size(), 2u);
    EXPECT_EQ(path->front().point.kind, SurfacePoint::Kind::kVertex);
    EXPECT_EQ(path->front().point.id, 5u);
    EXPECT_EQ(path->back().point.id, t);
    EXPECT_LT(RelativeError(PathLength(*path), (*d)[t]), 1e-9) << "target " << t;
  }
  // Face targets: distance and path agree, and exceed the straight line.
  std::uniform_int_distribution<FaceId> face(0, mesh_->num_faces() - 1);
  for (int i = 0; i < 20; ++i) {
    SurfacePoint target = SurfacePoint::Face(face(rng), 0.2, 0.5, 0.3);
    auto dist = exact.DistanceTo(target);
    ASSERT_OK(dist);
    auto path = exact.Trace(target);
    ASSERT_OK(path);
    EXPECT_LT(RelativeError(PathLength(*path), *dist), 1e-9);
    EXPECT_GE(*dist, Distance(mesh_->position(5), PositionOf(*mesh_, target)) * (1 - 1e-12));
  }
}

}  // namespace
}  // namespace geodesic
