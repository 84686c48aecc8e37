// Point-to-point queries and paths on a DGG against the independent exact
// solver's pairs (../shared/truth/<mesh>.p2p.*) and our exact engine.
#include <atomic>
#include <bit>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <thread>

#include "absl/strings/str_format.h"
#include "core/base/node_heap.h"
#include "core/dgg/dgg_graph_internal.h"
#include "core/exact/exact_geodesic.h"
#include "core/mesh/mesh_io.h"
#include "core/query/augmented_graph.h"
#include "core/query/build_dgg.h"
#include "core/query/field_lanes.h"
#include "core/query/field_solver.h"
#include "core/query/geodesic_engine.h"
#include "core/query/graph_search.h"
#include "tests/core/test_util.h"

namespace geodesic {
namespace {

using testing::SharedDataAvailable;
using testing::SharedPath;

double PolylineLength(const GeodesicPath& path) {
  double length = 0;
  for (size_t i = 1; i < path.points.size(); ++i) {
    length += Distance(path.points[i - 1].xyz, path.points[i].xyz);
  }
  return length;
}

// Every path point must be where its surface point says, and consecutive
// points must share a face (so each segment lies on the surface).
void ExpectOnSurface(const Mesh& mesh, const GeodesicPath& path) {
  auto faces_of = [&](const SurfacePoint& p) {
    std::vector<FaceId> faces;
    if (p.kind == SurfacePoint::Kind::kFace) {
      faces.push_back(p.id);
    } else if (p.kind == SurfacePoint::Kind::kEdge) {
      HalfedgeId h = mesh.edge_halfedge(p.id);
      faces.push_back(Mesh::face(h));
      if (mesh.twin(h) != kNone) faces.push_back(Mesh::face(mesh.twin(h)));
    } else {
      HalfedgeId h = mesh.vertex_halfedge(p.id), start = h;
      do {
        faces.push_back(Mesh::face(h));
        h = mesh.rotate(h);
      } while (h != kNone && h != start);
    }
    std::sort(faces.begin(), faces.end());
    return faces;
  };
  for (size_t i = 0; i < path.points.size(); ++i) {
    const PathPoint& p = path.points[i];
    EXPECT_LT(Distance(PositionOf(mesh, p.point), p.xyz), 1e-12) << "point " << i;
    if (i == 0) continue;
    auto a = faces_of(path.points[i - 1].point), b = faces_of(p.point);
    std::vector<FaceId> common;
    std::set_intersection(a.begin(), a.end(), b.begin(), b.end(), std::back_inserter(common));
    EXPECT_FALSE(common.empty()) << "segment " << i << " leaves the surface";
  }
}

// A planar grid of nx x ny squares of side h, and its graph at eps 1e-2
// (null, with a test failure, if the build fails).
std::pair<std::shared_ptr<const Mesh>, std::shared_ptr<const DggGraph>> GridAndGraph(int nx, int ny,
                                                                                     double h) {
  auto mesh = std::make_shared<const Mesh>(testing::PlanarGrid(nx, ny, h));
  DggBuildOptions options;
  options.params.epsilon = 1e-2;
  auto graph = BuildDgg(*mesh, options);
  EXPECT_OK(graph);
  return {mesh, graph.ok() ? *graph : nullptr};
}

// The bundled sample mesh and its graph at `eps` (null, with a test failure,
// if loading or the build fails).
std::pair<std::shared_ptr<const Mesh>, std::shared_ptr<const DggGraph>> SpotAndGraph(double eps) {
  auto loaded = LoadMesh(testing::SourcePath("data/spot.obj"));
  EXPECT_OK(loaded);
  if (!loaded.ok()) return {nullptr, nullptr};
  auto mesh = std::make_shared<const Mesh>(std::move(loaded).value());
  DggBuildOptions options;
  options.params.epsilon = eps;
  auto graph = BuildDgg(*mesh, options);
  EXPECT_OK(graph);
  return {mesh, graph.ok() ? *graph : nullptr};
}

struct Pair {
  SurfacePoint a, b;
  double exact;
};

std::vector<Pair> ReadPairs(const Mesh& mesh, const std::string& name) {
  std::ifstream pairs(SharedPath("truth/" + name + ".p2p.pairs"));
  std::ifstream exact(SharedPath("truth/" + name + ".p2p.exact"));
  std::vector<Pair> out;
  std::string a, b, d;
  while (pairs >> a >> b && exact >> d) {
    auto pa = ParseSurfacePointSpec(a);
    auto pb = ParseSurfacePointSpec(b);
    EXPECT_OK(pa);
    EXPECT_OK(pb);
    if (!pa.ok() || !pb.ok()) break;
    out.push_back({pa->point, pb->point, d == "nan" ? kInfinity : std::stod(d)});
  }
  return out;
}

// A shared mesh by name, whatever its file's extension.
absl::StatusOr<Mesh> LoadSharedMesh(const std::string& name) {
  for (const char* ext : {".off", ".obj", ".ply"}) {
    const std::string path = SharedPath("meshes/" + name + ext);
    if (std::filesystem::exists(path)) return LoadMesh(path);
  }
  return absl::NotFoundError("no shared mesh named " + name);
}

class PairsTest : public ::testing::TestWithParam<std::string> {};

TEST_P(PairsTest, WithinEpsilonOfExactPairsWithPathsOnTheSurface) {
  ASSERT_TRUE(SharedDataAvailable()) << "missing " << SharedPath("meshes/MANIFEST.md");
  const std::string name = GetParam();
  auto loaded = LoadSharedMesh(name);
  ASSERT_OK(loaded);
  auto mesh = std::make_shared<const Mesh>(std::move(loaded).value());
  const double eps = 1e-2;
  DggBuildOptions options;
  options.params.epsilon = eps;
  auto graph = BuildDgg(*mesh, options);
  ASSERT_OK(graph);
  GeodesicEngine engine(mesh, *graph);
  ASSERT_OK(engine.PrepareLandmarks());
  GeodesicEngine straight_line_only(mesh, *graph);
  auto pairs = ReadPairs(*mesh, name);
  ASSERT_GE(pairs.size(), 100u);
  double sum = 0;
  size_t count = 0;
  uint64_t settled_landmarks = 0, settled_straight = 0;
  for (size_t i = 0; i < pairs.size(); ++i) {
    const Pair& p = pairs[i];
    PairOptions with_path;
    with_path.want_path = i % 4 == 0;
    auto r = engine.Distance(p.a, p.b, with_path);
    ASSERT_OK(r);
    if (p.exact == kInfinity) {
      EXPECT_EQ(r->distance, kInfinity) << "pair " << i;
      continue;
    }
    if (p.exact == 0) continue;
    const double rel = (r->distance - p.exact) / p.exact;
    EXPECT_GE(rel, -1e-9) << "pair " << i;
    EXPECT_LE(rel, 1.5 * eps) << "pair " << i;
    sum += rel;
    ++count;
    if (r->path) {
      // The traced polyline is a real surface path: no shorter than the
      // exact distance, no longer than the graph's.
      EXPECT_NEAR(PolylineLength(*r->path), r->path->length, 1e-12 * r->distance) << "pair " << i;
      EXPECT_GE(r->path->length, p.exact * (1 - 1e-9)) << "pair " << i;
      EXPECT_LE(r->path->length, r->distance * (1 + 1e-9)) << "pair " << i;
      ExpectOnSurface(*mesh, *r->path);
    }
    // Plain bidirectional Dijkstra finds the same graph distance as A*. A
    // traced path is a real surface path no longer than the graph's: its
    // length lies between the exact distance and the graph distance.
    PairOptions plain;
    plain.use_astar = false;
    auto d = engine.Distance(p.a, p.b, plain);
    ASSERT_OK(d);
    auto graph_only = r->path ? engine.Distance(p.a, p.b, {}) : r;
    ASSERT_OK(graph_only);
    EXPECT_NEAR(graph_only->distance, d->distance, 1e-7 * d->distance) << "pair " << i;
    // One distance per pair, with or without its path.
    EXPECT_EQ(r->distance, graph_only->distance) << "pair " << i;
    EXPECT_LE(r->settled, d->settled + 1) << "A* settled more than Dijkstra on pair " << i;
    // Straight-line bounds alone: the same distance, more nodes settled.
    auto e = straight_line_only.Distance(p.a, p.b, {});
    ASSERT_OK(e);
    EXPECT_NEAR(e->distance, d->distance, 1e-9 * d->distance) << "pair " << i;
    settled_landmarks += r->settled;
    settled_straight += e->settled;
  }
  EXPECT_LT(sum / count, 0.3 * eps);
  // On these curved meshes landmarks at least halve the work.
  EXPECT_LT(2 * settled_landmarks, settled_straight);
}

INSTANTIATE_TEST_SUITE_P(SharedMeshes, PairsTest, ::testing::Values("camelhead", "fertility"));

// Exact pairs: the independent solver's distances to 1e-12 relative, and
// its paths' lengths, with far fewer windows than a whole propagation.
class ExactPairsTest : public ::testing::TestWithParam<std::string> {};

TEST_P(ExactPairsTest, EqualTheIndependentSolversPairsAndPaths) {
  ASSERT_TRUE(SharedDataAvailable()) << "missing " << SharedPath("meshes/MANIFEST.md");
  const std::string name = GetParam();
  auto loaded = LoadSharedMesh(name);
  ASSERT_OK(loaded);
  auto mesh = std::make_shared<const Mesh>(std::move(loaded).value());
  DggBuildOptions build;
  build.params.epsilon = 1e-2;
  auto graph = BuildDgg(*mesh, build);
  ASSERT_OK(graph);
  GeodesicEngine engine(mesh, *graph);
  auto pairs = ReadPairs(*mesh, name);
  ASSERT_GE(pairs.size(), 100u);
  ExactGeodesic whole(*mesh);
  size_t compared = 0;
  uint64_t pruned_windows = 0, whole_windows = 0;
  for (size_t i = 0; i < pairs.size(); i += 3) {
    const Pair& p = pairs[i];
    PairOptions options;
    options.exact = true;
    options.want_path = i % 2 == 0;
    auto r = engine.Distance(p.a, p.b, options);
    ASSERT_OK(r);
    EXPECT_TRUE(r->exact);
    if (p.exact == kInfinity) {
      EXPECT_EQ(r->distance, kInfinity) << "pair " << i;
      continue;
    }
    ASSERT_TRUE(std::isfinite(r->distance)) << "pair " << i;
    EXPECT_NEAR(r->distance, p.exact, 1e-12 * std::max(p.exact, 1e-300)) << "pair " << i;
    ++compared;
    if (r->path) {
      ASSERT_FALSE(r->path->points.empty()) << "pair " << i;
      EXPECT_NEAR(r->path->length, p.exact, 1e-9 * std::max(p.exact, 1e-300)) << "pair " << i;
      ExpectOnSurface(*mesh, *r->path);
    }
    // The same propagation without the goal sweeps the whole disc.
    if (i % 15 == 0 && p.exact > 0) {
      ExactOptions disc;
      disc.max_distance = p.exact * (1 + 1e-9);
      ASSERT_OK(whole.Distances(p.a, disc));
      pruned_windows += r->windows;
      whole_windows += whole.stats().windows_created;
    }
  }
  EXPECT_GE(compared, 30u);
  ASSERT_GT(whole_windows, 0u);
  EXPECT_LT(2 * pruned_windows, whole_windows) << "the goal pruned less than half the windows";

  // With exact landmarks: the same answers, from fewer windows. The graph's
  // answers are the same to the bit: their joins then read the landmarks'
  // face frames instead of computing them.
  uint64_t windows_straight = 0, windows_landmarks = 0;
  std::vector<double> straight, on_graph;
  PairOptions exact_only;
  exact_only.exact = true;
  for (size_t i = 0; i < pairs.size(); i += 3) {
    auto r = engine.Distance(pairs[i].a, pairs[i].b, exact_only);
    ASSERT_OK(r);
    straight.push_back(r->distance);
    windows_straight += r->windows;
    auto g = engine.Distance(pairs[i].a, pairs[i].b, PairOptions());
    ASSERT_OK(g);
    on_graph.push_back(g->distance);
  }
  ASSERT_OK(engine.PrepareExactLandmarks(8));
  EXPECT_EQ(engine.exact_landmark_bytes(),
            ExactLandmarks::ByteSize(mesh->num_vertices(), mesh->num_halfedges(), 8));
  for (size_t i = 0, k = 0; i < pairs.size(); i += 3, ++k) {
    const Pair& p = pairs[i];
    auto g = engine.Distance(p.a, p.b, PairOptions());
    ASSERT_OK(g);
    EXPECT_EQ(g->distance, on_graph[k]) << "pair " << i;
    auto r = engine.Distance(p.a, p.b, exact_only);
    ASSERT_OK(r);
    windows_landmarks += r->windows;
    if (p.exact == kInfinity) {
      EXPECT_EQ(r->distance, kInfinity) << "pair " << i;
      continue;
    }
    ASSERT_TRUE(std::isfinite(r->distance)) << "pair " << i;
    EXPECT_NEAR(r->distance, p.exact, 1e-12 * std::max(p.exact, 1e-300)) << "pair " << i;
    EXPECT_NEAR(r->distance, straight[k], 1e-13 * std::max(p.exact, 1e-300)) << "pair " << i;
  }
  ASSERT_GT(windows_landmarks, 0u);
  EXPECT_LT(5 * windows_landmarks, 4 * windows_straight)
      << "landmarks saved less than a fifth of the windows";
}

INSTANTIATE_TEST_SUITE_P(SharedMeshes, ExactPairsTest, ::testing::Values("camelhead", "fertility"));

TEST(QueriesTest, SameFaceAndCornerCasesOnAGrid) {
  auto [mesh, graph] = GridAndGraph(20, 20, 0.1);
  ASSERT_NE(graph, nullptr);
  GeodesicEngine engine(mesh, graph);
  const SurfacePoint points[] = {SurfacePoint::Face(5, 0.2, 0.3, 0.5),
                                 SurfacePoint::Face(5, 0.6, 0.3, 0.1),
                                 SurfacePoint::Edge(7, 0.25),
                                 SurfacePoint::Vertex(0),
                                 SurfacePoint::Vertex(440),
                                 SurfacePoint::Face(700, 0.1, 0.1, 0.8)};
  PairOptions with_path;
  with_path.want_path = true;
  for (const SurfacePoint& a : points) {
    for (const SurfacePoint& b : points) {
      auto r = engine.Distance(a, b, with_path);
      ASSERT_OK(r);
      const double straight = Distance(PositionOf(*mesh, a), PositionOf(*mesh, b));
      EXPECT_GE(r->distance, straight * (1 - 1e-9));
      EXPECT_LE(r->distance, straight * (1 + 1.5e-2) + 1e-12);
      ASSERT_TRUE(r->path.has_value());
      EXPECT_NEAR(PolylineLength(*r->path), r->path->length, 1e-12 * r->distance + 1e-15);
      EXPECT_LE(r->path->length, r->distance * (1 + 1e-9) + 1e-15);
      EXPECT_GE(r->path->length, straight * (1 - 1e-9));
      // One distance per pair, with or without its path.
      auto without = engine.Distance(a, b, {});
      ASSERT_OK(without);
      EXPECT_EQ(r->distance, without->distance);
    }
  }
}

TEST(QueriesTest, ABatchOfPairsAnswersAsEachPairAlone) {
  auto [mesh, graph] = GridAndGraph(30, 30, 0.1);
  ASSERT_NE(graph, nullptr);
  GeodesicEngine engine(mesh, graph);
  std::mt19937 rng(11);
  std::uniform_int_distribution<uint32_t> face(0, mesh->num_faces() - 1);
  std::uniform_real_distribution<double> unit(0.05, 1.0);
  std::vector<SurfacePoint> from, to;
  for (int i = 0; i < 64; ++i) {
    for (auto* side : {&from, &to}) {
      const double a = unit(rng), b = unit(rng), c = unit(rng);
      side->push_back(
          SurfacePoint::Face(face(rng), a / (a + b + c), b / (a + b + c), c / (a + b + c)));
    }
  }
  for (bool want_path : {false, true}) {
    PairOptions options;
    options.want_path = want_path;
    auto batch = engine.Distances(from, to, options);
    ASSERT_OK(batch);
    ASSERT_EQ(batch->size(), from.size());
    for (size_t i = 0; i < from.size(); ++i) {
      auto alone = engine.Distance(from[i], to[i], options);
      ASSERT_OK(alone);
      ASSERT_TRUE(std::isfinite(alone->distance) && alone->distance > 0);
      EXPECT_EQ((*batch)[i].distance, alone->distance) << "pair " << i;
      EXPECT_EQ((*batch)[i].path.has_value(), want_path);
    }
  }
  // The lowest failing pair's error, whatever finished first.
  to[40] = SurfacePoint::Vertex(1u << 30);
  to[50] = SurfacePoint::Vertex(1u << 29);
  auto bad = engine.Distances(from, to, {});
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.status().code(), absl::StatusCode::kOutOfRange) << bad.status();
  EXPECT_THAT(std::string(bad.status().message()), ::testing::HasSubstr(std::to_string(1u << 30)));
  EXPECT_FALSE(engine.Distances(from, absl::MakeConstSpan(to).subspan(1), {}).ok());
}

// The search's shortcuts (each node relaxes only the fan of the edge it came
// by, A* with landmark bounds, two sides meeting) lose no distance: pairs of
// face points equal the plain Dijkstra field from the first point, which
// relaxes every edge of every node, continued by the second point's direct
// geodesics (or the direct geodesic between them), to the rounding of the
// weights' sums.
TEST(QueriesTest, PairsEqualADijkstraRelaxingEveryEdgeOfTheAugmentedGraph) {
  auto [mesh, graph] = SpotAndGraph(1e-3);
  ASSERT_TRUE(graph);
  GeodesicEngine engine(mesh, graph);
  ASSERT_OK(engine.PrepareLandmarks(engine.DefaultLandmarkCount()));
  ExactGeodesic exact(*mesh);
  std::mt19937 rng(11);
  std::uniform_int_distribution<FaceId> face(0, mesh->num_faces() - 1);
  std::uniform_real_distribution<double> unit(0.05, 0.9);
  auto random_point = [&] {
    const double u = unit(rng), v = (1 - u) * unit(rng);
    return SurfacePoint::Face(face(rng), u, v, 1 - u - v);
  };
  FieldOptions every_edge;
  every_edge.method = FieldMethod::kDijkstra;
  for (int i = 0; i < 40; ++i) {
    const SurfacePoint a = random_point(), b = random_point();
    auto field = engine.Field({&a, 1}, every_edge);
    ASSERT_OK(field);
    DirectOptions options;
    options.epsilon = graph->params().epsilon;
    auto to_b = exact.DirectGeodesics(b, options);
    ASSERT_OK(to_b);
    ASSERT_FALSE(to_b->empty());
    options.keep_windows = true;
    auto from_a = exact.DirectGeodesics(a, options);
    ASSERT_OK(from_a);
    ASSERT_FALSE(from_a->empty());
    auto direct = exact.DistanceTo(b);
    ASSERT_OK(direct);
    double want = *direct;
    for (const DirectHit& h : *to_b) want = std::min(want, field->distance[h.vertex] + h.distance);
    ASSERT_LT(want, kInfinity) << "pair " << i;
    auto got = engine.Distance(a, b, {});
    ASSERT_OK(got);
    ASSERT_GT(got->distance, 0) << "pair " << i;
    EXPECT_NEAR(got->distance, want, 1e-6 * want) << "pair " << i;
  }
}

TEST(QueriesTest, DifferentComponentsAreUnreachable) {
  TriangleSoup soup;
  soup.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {5, 0, 0}, {6, 0, 0}, {5, 1, 0}};
  soup.triangles = {{0, 1, 2}, {3, 4, 5}};
  auto mesh = std::make_shared<const Mesh>(testing::MustBuild(soup));
  DggBuildOptions options;
  options.params.epsilon = 1e-2;
  auto graph = BuildDgg(*mesh, options);
  ASSERT_OK(graph);
  GeodesicEngine engine(mesh, *graph);
  // One component has no landmark: its nodes get no bound, still no error.
  ASSERT_OK(engine.PrepareLandmarks(2));
  PairOptions with_path;
  with_path.want_path = true;
  auto r =
      engine.Distance(SurfacePoint::Face(0, 0.3, 0.3, 0.4), SurfacePoint::Vertex(4), with_path);
  ASSERT_OK(r);
  EXPECT_EQ(r->distance, kInfinity);
  EXPECT_FALSE(r->path.has_value());
  // Within each component, whether or not a landmark is in it.
  for (VertexId a : {VertexId{0}, VertexId{3}}) {
    auto within = engine.Distance(SurfacePoint::Vertex(a), SurfacePoint::Vertex(a + 1), {});
    ASSERT_OK(within);
    EXPECT_NEAR(within->distance, 1.0, 1e-6) << "from vertex " << a;
  }
  auto m =
      engine.Matrix(std::vector<SurfacePoint>{SurfacePoint::Vertex(0)},
                    std::vector<SurfacePoint>{SurfacePoint::Vertex(1), SurfacePoint::Vertex(5)});
  ASSERT_OK(m);
  EXPECT_DOUBLE_EQ((*m)[0], 1.0);
  EXPECT_EQ((*m)[1], kInfinity);
}

TEST(LandmarksTest, DistancesAreGraphDistancesFromFarApartNodes) {
  auto [mesh, graph] = GridAndGraph(15, 10, 0.1);
  ASSERT_NE(graph, nullptr);
  auto landmarks = Landmarks::Compute(*graph, 4);
  ASSERT_OK(landmarks);
  const Landmarks& l = **landmarks;
  ASSERT_EQ(l.count(), 4);
  GeodesicEngine engine(mesh, graph);
  std::vector<Vec3> where;
  for (int k = 0; k < l.count(); ++k) {
    const uint32_t node = l.nodes()[k];
    ASSERT_LT(node, mesh->num_vertices());
    const VertexId vertex = graph->vertex_of_node(node);
    where.push_back(mesh->position(vertex));
    const SurfacePoint source = SurfacePoint::Vertex(vertex);
    auto field = engine.Field(absl::MakeConstSpan(&source, 1), {});
    ASSERT_OK(field);
    for (VertexId v = 0; v < mesh->num_vertices(); ++v) {
      EXPECT_NEAR(l.of(graph->node_of_vertex(v))[k], field->distance[v], 1e-6 * field->distance[v])
          << k << " " << v;
    }
  }
  // Farthest-point sampling on a 1.5 x 1 rectangle: first two opposite
  // corners, then points on the border.
  EXPECT_NEAR(Distance(where[0], where[1]), std::hypot(1.5, 1.0), 1e-9);
  for (const Vec3& p : where) {
    const double to_border = std::min({p.x, 1.5 - p.x, p.y, 1.0 - p.y});
    EXPECT_LT(to_border, 1e-9) << p.x << " " << p.y;
  }
  for (int i = 0; i < 4; ++i) {
    for (int j = 0; j < i; ++j) EXPECT_NE(l.nodes()[i], l.nodes()[j]);
  }
}

TEST(LandmarksTest, CancelledPreparationLeavesQueriesWorking) {
  auto [mesh, graph] = GridAndGraph(10, 10, 0.1);
  ASSERT_NE(graph, nullptr);
  GeodesicEngine engine(mesh, graph);
  EXPECT_EQ(engine.PrepareLandmarks(8, [] { return true; }).code(), absl::StatusCode::kCancelled);
  EXPECT_EQ(engine.landmark_bytes(), 0u);
  auto before = engine.Distance(SurfacePoint::Vertex(0), SurfacePoint::Vertex(99), {});
  ASSERT_OK(before);
  ASSERT_OK(engine.PrepareLandmarks(8));
  EXPECT_EQ(engine.landmark_bytes(), 8u * graph->num_nodes() * sizeof(float));
  // What a server counts while they are computed covers what they keep.
  EXPECT_GT(Landmarks::ComputeBytes(*graph, 8), engine.landmark_bytes());
  auto after = engine.Distance(SurfacePoint::Vertex(0), SurfacePoint::Vertex(99), {});
  ASSERT_OK(after);
  EXPECT_DOUBLE_EQ(after->distance, before->distance);
  EXPECT_LE(after->settled, before->settled);
}

// Many threads on one engine, as the daemon runs them, while another thread
// publishes the landmarks: every answer equals the one-thread answer.
TEST(QueriesTest, ConcurrentQueriesWhileLandmarksArePrepared) {
  auto loaded = LoadMesh(testing::SourcePath("data/spot.obj"));
  ASSERT_OK(loaded);
  auto mesh = std::make_shared<const Mesh>(std::move(*loaded));
  DggBuildOptions options;
  options.params.epsilon = 1e-2;
  auto graph = BuildDgg(*mesh, options);
  ASSERT_OK(graph);
  std::vector<std::pair<SurfacePoint, SurfacePoint>> pairs;
  std::mt19937 rng(7);
  std::uniform_int_distribution<uint32_t> vertex(0, mesh->num_vertices() - 1);
  std::uniform_int_distribution<uint32_t> face(0, mesh->num_faces() - 1);
  for (int i = 0; i < 24; ++i) {
    pairs.push_back(
        {SurfacePoint::Vertex(vertex(rng)),
         i % 2 ? SurfacePoint::Vertex(vertex(rng)) : SurfacePoint::Face(face(rng), 0.2, 0.3, 0.5)});
  }
  const SurfacePoint source = SurfacePoint::Vertex(11);
  std::vector<double> want;
  GeodesicEngine reference(mesh, *graph);
  for (const auto& [a, b] : pairs) {
    auto r = reference.Distance(a, b, {});
    ASSERT_OK(r);
    want.push_back(r->distance);
  }
  auto want_field = reference.Field(absl::MakeConstSpan(&source, 1), {});
  ASSERT_OK(want_field);

  GeodesicEngine shared(mesh, *graph);
  std::atomic<int> mismatches{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&, t] {
      for (int round = 0; round < 3; ++round) {
        for (size_t i = t; i < pairs.size(); i += 2) {
          auto r = shared.Distance(pairs[i].first, pairs[i].second, {});
          if (!r.ok() || std::abs(r->distance - want[i]) > 1e-12 * want[i]) ++mismatches;
        }
        auto f = shared.Field(absl::MakeConstSpan(&source, 1), {});
        if (!f.ok() || f->distance != want_field->distance) ++mismatches;
      }
    });
  }
  threads.emplace_back([&] { EXPECT_OK(shared.PrepareLandmarks()); });
  for (auto& t : threads) t.join();
  EXPECT_EQ(mismatches.load(), 0);
  EXPECT_GT(shared.landmark_bytes(), 0u);
}

TEST(QueriesTest, BadPointsGetPreciseCodes) {
  auto [mesh, graph] = GridAndGraph(4, 4, 1.0);
  ASSERT_NE(graph, nullptr);
  GeodesicEngine engine(mesh, graph);
  EXPECT_EQ(engine.Distance(SurfacePoint::Vertex(99), SurfacePoint::Vertex(0), {}).status().code(),
            absl::StatusCode::kOutOfRange);
  EXPECT_EQ(
      engine.Distance(SurfacePoint::Face(0, -1, 1, 1), SurfacePoint::Vertex(0), {}).status().code(),
      absl::StatusCode::kInvalidArgument);
  SurfacePoint nan_point = SurfacePoint::Face(0, std::nan(""), 0.5, 0.5);
  EXPECT_EQ(engine.Field(absl::MakeConstSpan(&nan_point, 1), {}).status().code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(engine.Field({}, {}).status().code(), absl::StatusCode::kInvalidArgument);
}

// Random points of every kind: vertices, points on edges (ends included:
// t = 0 and 1 are vertices in disguise), points inside faces, several of them
// in one face, and one point twice.
std::vector<SurfacePoint> MixedPoints(const Mesh& mesh, uint32_t seed) {
  std::mt19937 rng(seed);
  auto below = [&](uint32_t n) { return std::uniform_int_distribution<uint32_t>(0, n - 1)(rng); };
  std::uniform_real_distribution<double> unit(0.05, 0.95);
  std::vector<SurfacePoint> points;
  for (int i = 0; i < 5; ++i) points.push_back(SurfacePoint::Vertex(below(mesh.num_vertices())));
  for (int i = 0; i < 5; ++i)
    points.push_back(SurfacePoint::Edge(below(mesh.num_edges()), unit(rng)));
  points.push_back(SurfacePoint::Edge(below(mesh.num_edges()), 0.0));
  points.push_back(SurfacePoint::Edge(below(mesh.num_edges()), 1.0));
  auto face_point = [&](FaceId f) {
    double b0 = unit(rng), b1 = unit(rng) * (1 - b0);
    return SurfacePoint::Face(f, b0, b1, 1 - b0 - b1);
  };
  for (int i = 0; i < 5; ++i) points.push_back(face_point(below(mesh.num_faces())));
  const FaceId shared = below(mesh.num_faces());
  for (int i = 0; i < 3; ++i) points.push_back(face_point(shared));
  points.push_back(SurfacePoint::Face(shared, 0.2, 0.3, 0.5));
  points.push_back(SurfacePoint::Face(shared, 0.25, 0.3, 0.45));
  points.push_back(points[7]);  // the same edge point again
  return points;
}

// A matrix entry is the pair's distance, to the last bit: Matrix and
// Distance join points to the graph the same way and sum a path's hops in
// the same order (SumAlongRoute in core/query/point_to_point.cc). A point's distance to itself
// is 0, whatever kind of point it is.
void ExpectMatrixEqualsPairs(const GeodesicEngine& engine,
                             const std::vector<SurfacePoint>& points) {
  auto m = engine.Matrix(points, points);
  ASSERT_OK(m);
  const size_t n = points.size();
  ASSERT_EQ(m->size(), n * n);
  for (size_t i = 0; i < n; ++i) {
    for (size_t j = 0; j < n; ++j) {
      const double entry = (*m)[i * n + j];
      const std::string pair =
          FormatSurfacePoint(points[i]) + " -> " + FormatSurfacePoint(points[j]);
      auto d = engine.Distance(points[i], points[j], {});
      ASSERT_OK(d);
      EXPECT_EQ(entry, d->distance) << pair;
      const double straight =
          Distance(PositionOf(engine.mesh(), points[i]), PositionOf(engine.mesh(), points[j]));
      EXPECT_GE(entry, straight * (1 - 1e-12)) << pair;
      if (PositionOf(engine.mesh(), points[i]) == PositionOf(engine.mesh(), points[j])) {
        EXPECT_EQ(entry, 0) << pair;
      }
    }
  }
}

TEST(QueriesTest, MatrixEqualsPairsOnAGrid) {
  auto [mesh, graph] = GridAndGraph(12, 12, 0.2);
  ASSERT_NE(graph, nullptr);
  GeodesicEngine engine(mesh, graph);
  ExpectMatrixEqualsPairs(engine, MixedPoints(*mesh, 7));
}

// The bundled sample mesh at the epsilon the daemon serves by default:
// where a user found face points of one face joined only through vertices.
TEST(QueriesTest, MatrixEqualsPairsOnSpot) {
  auto [mesh, graph] = SpotAndGraph(1e-3);
  ASSERT_NE(graph, nullptr);
  GeodesicEngine engine(mesh, graph);
  ASSERT_OK(engine.PrepareLandmarks());
  ExpectMatrixEqualsPairs(engine, MixedPoints(*mesh, 11));
  // The user's report: the same face point twice, and a neighbour in its face.
  const std::vector<SurfacePoint> sources = {SurfacePoint::Face(0, 0.2, 0.3, 0.5)};
  const std::vector<SurfacePoint> targets = {SurfacePoint::Face(0, 0.2, 0.3, 0.5),
                                             SurfacePoint::Face(0, 0.25, 0.3, 0.45)};
  auto m = engine.Matrix(sources, targets);
  ASSERT_OK(m);
  EXPECT_EQ((*m)[0], 0);
  const double straight = Distance(PositionOf(*mesh, sources[0]), PositionOf(*mesh, targets[1]));
  EXPECT_NEAR((*m)[1], straight, 1e-12 * straight);  // one face: a straight segment
}

// StreamMatrix hands over Matrix's rows, bit for bit, each once, and in
// batches: when batch_done(end) runs, every row before `end` has arrived and
// none after it, so a sink can append rows in order holding one batch.
TEST(QueriesTest, StreamMatrixDeliversMatrixRowsInBatches) {
  auto [mesh, graph] = GridAndGraph(12, 12, 0.2);
  ASSERT_NE(graph, nullptr);
  GeodesicEngine engine(mesh, graph);
  const std::vector<SurfacePoint> points = MixedPoints(*mesh, 7);
  auto m = engine.Matrix(points, points);
  ASSERT_OK(m);
  const size_t n = points.size();
  ASSERT_GT(n, 5u);
  std::vector<double> streamed(n * n, -1);
  std::vector<std::atomic<int>> deliveries(n);
  std::vector<size_t> batch_ends;
  MatrixRowSink sink;
  sink.batch_rows = 3;
  sink.row = [&](size_t i, absl::Span<const double> row) {
    EXPECT_EQ(row.size(), n);
    std::copy(row.begin(), row.end(), streamed.begin() + i * n);
    ++deliveries[i];
    return absl::OkStatus();
  };
  sink.batch_done = [&](size_t end) {
    for (size_t i = 0; i < n; ++i) EXPECT_EQ(deliveries[i], i < end ? 1 : 0) << i << " " << end;
    batch_ends.push_back(end);
    return absl::OkStatus();
  };
  ASSERT_OK(engine.StreamMatrix(points, points, MatrixOptions{}, sink));
  EXPECT_EQ(streamed, *m);
  std::vector<size_t> expected_ends;
  for (size_t end = 3; end < n + 3; end += 3) expected_ends.push_back(std::min(end, n));
  EXPECT_EQ(batch_ends, expected_ends);
  // A sink's error stops the stream and is returned.
  sink.row = [](size_t i, absl::Span<const double>) {
    return i == 4 ? absl::DataLossError("disk gone") : absl::OkStatus();
  };
  sink.batch_done = nullptr;
  EXPECT_EQ(engine.StreamMatrix(points, points, MatrixOptions{}, sink).code(),
            absl::StatusCode::kDataLoss);
}

// Rows come from several sources per sweep of the graph (core/query/field_lanes.h);
// each still equals that source's own field, to the last bit, and the graph
// is symmetric, so the all-vertices matrix is too.
TEST(QueriesTest, MatrixRowsEqualSingleSourceFieldsOnSpot) {
  auto [mesh, graph] = SpotAndGraph(1e-3);
  ASSERT_NE(graph, nullptr);
  GeodesicEngine engine(mesh, graph);
  const size_t n = mesh->num_vertices();
  std::vector<SurfacePoint> all;
  for (VertexId v = 0; v < n; ++v) all.push_back(SurfacePoint::Vertex(v));
  auto m = engine.Matrix(all, all);
  ASSERT_OK(m);
  ASSERT_EQ(m->size(), n * n);
  size_t finite = 0;
  for (VertexId s = 0; s < n; s += 7) {
    const std::vector<SurfacePoint> source = {SurfacePoint::Vertex(s)};
    auto field = engine.Field(source, {});
    ASSERT_OK(field);
    ASSERT_EQ(field->distance.size(), n);
    for (VertexId t = 0; t < n; ++t) {
      ASSERT_EQ((*m)[s * n + t], field->distance[t]) << s << " -> " << t;
      finite += std::isfinite(field->distance[t]);
    }
  }
  EXPECT_GT(finite, n);
  for (size_t i = 0; i < n; ++i) {
    for (size_t j = 0; j < i; ++j) ASSERT_EQ((*m)[i * n + j], (*m)[j * n + i]) << i << " " << j;
  }
}

// A sink of float32 rows gets each float64 row rounded, to the last bit:
// rows of vertex sources, which go from the sweep's lanes straight to
// float32, and rows of edge and face points, which hold direct geodesics
// first; with and without a distance limit. Narrowing the fans as rows come
// in changes none of them.
TEST(QueriesTest, Float32RowsAreFloat64RowsRounded) {
  auto [mesh, graph] = SpotAndGraph(1e-3);
  ASSERT_NE(graph, nullptr);
  GeodesicEngine engine(mesh, graph);
  std::vector<SurfacePoint> vertices, targets = MixedPoints(*mesh, 11);
  // Every vertex: rows enough for the fans to narrow.
  for (VertexId v = 0; v < mesh->num_vertices(); ++v) vertices.push_back(SurfacePoint::Vertex(v));
  targets.insert(targets.end(), vertices.begin(), vertices.end());
  for (const std::vector<SurfacePoint>& sources : {vertices, MixedPoints(*mesh, 5)}) {
    for (double limit : {kInfinity, 0.5}) {
      MatrixOptions options;
      options.max_distance = limit;
      auto wide = engine.Matrix(sources, targets, options);
      ASSERT_OK(wide);
      for (bool narrow_fans : {false, true}) {
        SCOPED_TRACE(absl::StrFormat("%u sources, limit %g, fans narrowed %d", sources.size(),
                                     limit, narrow_fans));
        options.narrow_fans = narrow_fans;
        if (narrow_fans) {
          auto narrowed = engine.Matrix(sources, targets, options);
          ASSERT_OK(narrowed);
          ASSERT_EQ(*narrowed, *wide);
        }
        const size_t cols = targets.size();
        std::vector<float> rounded(sources.size() * cols, -1);
        MatrixRowSink sink;
        sink.float32_row = [&](size_t i, absl::Span<const float> row) {
          EXPECT_EQ(row.size(), cols);
          std::copy(row.begin(), row.end(), rounded.begin() + i * cols);
          return absl::OkStatus();
        };
        ASSERT_OK(engine.StreamMatrix(sources, targets, options, sink));
        size_t finite = 0, beyond = 0;
        for (size_t e = 0; e < rounded.size(); ++e) {
          ASSERT_EQ(std::bit_cast<uint32_t>(rounded[e]),
                    std::bit_cast<uint32_t>(static_cast<float>((*wide)[e])))
              << "entry " << e << ": " << rounded[e] << " against " << (*wide)[e];
          finite += std::isfinite(rounded[e]);
          beyond += std::isinf(rounded[e]);
        }
        EXPECT_GT(finite, rounded.size() / 8);
        if (limit < kInfinity) {
          EXPECT_GT(beyond, rounded.size() / 8);
        } else {
          EXPECT_EQ(finite, rounded.size());
        }
      }
    }
  }
}

// Spot's graph at 1e-3 and a full sweep's sources on it: vertices, edge and
// face points.
struct SpotLaneSweep {
  std::shared_ptr<const Mesh> mesh;
  std::shared_ptr<const DggGraph> graph;
  BucketShape shape;
  QueryScratch sc;
  std::vector<query_internal::Endpoint> sources;
  uint32_t nodes = 0;

  SpotLaneSweep() {
    std::tie(mesh, graph) = SpotAndGraph(1e-3);
    if (!graph) return;
    shape = BucketShapeOf(*graph);
    nodes = graph->num_nodes();
    for (const SurfacePoint& p : MixedPoints(*mesh, 5)) {
      if (sources.size() == kFieldLanes) break;
      auto end = query_internal::JoinToGraph(*mesh, *graph, sc, p, false);
      EXPECT_OK(end);
      if (end.ok()) sources.push_back(*std::move(end));
    }
  }
  bool ok() const { return graph && sources.size() == kFieldLanes; }
};

// A sweep keeps its lanes' fans packed when every node has fewer than 2^16
// edges, as here, and whole on graphs with larger nodes, and reads the
// graph's edges or a compact copy (packed fans only): the same labels
// either way, to the last bit, after the same work.
TEST(QueriesTest, LaneSweepsAreTheSameWhateverTheFansAndEdgesLayout) {
  SpotLaneSweep spot;
  ASSERT_TRUE(spot.ok());
  auto& [mesh, graph, shape, sc, sources, nodes] = spot;
  ASSERT_EQ(LaneFanLayoutFor(*graph), LaneFanLayout::kPacked);
  auto packed = query_internal::SolveFieldLanes(*graph, shape, LaneFanLayout::kPacked, nullptr, sc,
                                                sources, kInfinity, nullptr);
  ASSERT_OK(packed);
  const std::vector<LaneLabels> labels(sc.lane_dist.begin(), sc.lane_dist.begin() + nodes);
  EXPECT_GT(packed->relaxed, nodes);
  size_t finite = 0;
  for (uint32_t u = 0; u < nodes; ++u) {
    for (int k = 0; k < kFieldLanes; ++k) finite += std::isfinite(labels[u].dist[k]);
  }
  EXPECT_EQ(finite, size_t{nodes} * kFieldLanes);
  // The same sweep with fans whole, and with the graph's edges copied
  // compact (packed fans only).
  const std::optional<query_internal::CompactLaneEdges> compact =
      query_internal::CompactLaneEdges::Of(*graph);
  ASSERT_TRUE(compact.has_value());
  EXPECT_EQ(compact->bytes(), graph->edges().size() * 12);
  EXPECT_EQ(query_internal::SolveFieldLanes(*graph, shape, LaneFanLayout::kWhole, &*compact, sc,
                                            sources, kInfinity, nullptr)
                .status()
                .code(),
            absl::StatusCode::kInvalidArgument);
  for (const auto& [layout, edges] :
       {std::pair{LaneFanLayout::kWhole, (const query_internal::CompactLaneEdges*)nullptr},
        std::pair{LaneFanLayout::kPacked, &*compact}}) {
    SCOPED_TRACE(edges ? "compact edges" : "fans whole");
    auto other = query_internal::SolveFieldLanes(*graph, shape, layout, edges, sc, sources,
                                                 kInfinity, nullptr);
    ASSERT_OK(other);
    EXPECT_EQ(packed->relaxed, other->relaxed);
    EXPECT_EQ(packed->queue_pops, other->queue_pops);
    for (uint32_t u = 0; u < nodes; ++u) {
      for (int k = 0; k < kFieldLanes; ++k) {
        ASSERT_EQ(labels[u].dist[k], sc.lane_dist[u].dist[k]) << "node " << u << " lane " << k;
      }
    }
  }
}

// A single field keeps its fans packed where the graph allows, as here, and
// whole elsewhere: the same field, to the last bit, after the same work,
// from spot's mixed points (vertices, edge and face points).
TEST(QueriesTest, FieldsAreTheSameWithFansWholeOrPacked) {
  SpotLaneSweep spot;
  ASSERT_TRUE(spot.ok());
  auto& [mesh, graph, shape, sc, sources, nodes] = spot;
  FieldOptions options;
  options.nearest_source = true;
  auto packed = query_internal::SolveField(*mesh, *graph, shape, LaneFanLayout::kPacked, sc,
                                           sources, options);
  ASSERT_OK(packed);
  ASSERT_EQ(packed->distance.size(), mesh->num_vertices());
  for (double d : packed->distance) ASSERT_TRUE(std::isfinite(d));
  EXPECT_GT(packed->relaxed, nodes);
  auto whole =
      query_internal::SolveField(*mesh, *graph, shape, LaneFanLayout::kWhole, sc, sources, options);
  ASSERT_OK(whole);
  EXPECT_EQ(packed->distance, whole->distance);
  EXPECT_EQ(packed->nearest_source, whole->nearest_source);
  EXPECT_EQ(packed->relaxed, whole->relaxed);
  EXPECT_EQ(packed->queue_pops, whole->queue_pops);
}

// Narrows a compact copy of spot's edges by `narrow` (which returns how
// many fewer edges the fans hold), then checks that a sweep from spot's
// points (vertices, edge and face points) finds the same labels as before,
// to the last bit, relaxing fewer edges.
void ExpectNarrowingKeepsEveryLabel(
    SpotLaneSweep& spot, const std::function<uint64_t(query_internal::CompactLaneEdges&)>& narrow) {
  auto& [mesh, graph, shape, sc, sources, nodes] = spot;
  std::optional<query_internal::CompactLaneEdges> compact =
      query_internal::CompactLaneEdges::Of(*graph);
  ASSERT_TRUE(compact.has_value());
  auto before = query_internal::SolveFieldLanes(*graph, shape, LaneFanLayout::kPacked, &*compact,
                                                sc, sources, kInfinity, nullptr);
  ASSERT_OK(before);
  const std::vector<LaneLabels> labels(sc.lane_dist.begin(), sc.lane_dist.begin() + nodes);

  EXPECT_GT(narrow(*compact), graph->edges().size() / 20);

  auto after = query_internal::SolveFieldLanes(*graph, shape, LaneFanLayout::kPacked, &*compact, sc,
                                               sources, kInfinity, nullptr);
  ASSERT_OK(after);
  EXPECT_GT(after->relaxed, nodes);
  EXPECT_LT(after->relaxed, before->relaxed);
  size_t finite = 0;
  for (uint32_t u = 0; u < nodes; ++u) {
    for (int k = 0; k < kFieldLanes; ++k) {
      ASSERT_EQ(labels[u].dist[k], sc.lane_dist[u].dist[k]) << "node " << u << " lane " << k;
      finite += std::isfinite(labels[u].dist[k]);
    }
  }
  EXPECT_EQ(finite, size_t{nodes} * kFieldLanes);
}

// Once every vertex's row has narrowed its edges' fans, a sweep keeps every
// label and relaxes fewer edges.
TEST(QueriesTest, NarrowedFansKeepEveryLabelAndRelaxFewerEdges) {
  SpotLaneSweep spot;
  ASSERT_TRUE(spot.ok());
  ExpectNarrowingKeepsEveryLabel(spot, [&](query_internal::CompactLaneEdges& compact) {
    auto& [mesh, graph, shape, sc, sources, nodes] = spot;
    uint64_t dropped = 0;
    for (VertexId first = 0; first < mesh->num_vertices(); first += kFieldLanes) {
      std::vector<query_internal::Endpoint> group;
      for (VertexId v = first; v < std::min<VertexId>(first + kFieldLanes, mesh->num_vertices());
           ++v) {
        auto end = query_internal::JoinToGraph(*mesh, *graph, sc, SurfacePoint::Vertex(v), false);
        EXPECT_OK(end);
        if (!end.ok()) return dropped;
        group.push_back(*std::move(end));
      }
      EXPECT_OK(query_internal::SolveFieldLanes(*graph, shape, LaneFanLayout::kPacked, &compact, sc,
                                                group, kInfinity, nullptr));
      for (size_t k = 0; k < group.size(); ++k) {
        dropped += compact.NarrowFans(*graph, group[k].node, sc.lane_dist, k);
      }
    }
    return dropped;
  });
}

// A sweep with a limit resets, before it, only the nodes the scratch's last
// bounded sweep reached: whatever ran on the scratch before (bounded sweeps
// of other sources and limits, a full sweep, a cancelled one), every node's
// labels come out as from a fresh scratch, to the last bit.
TEST(QueriesTest, BoundedSweepsResetWhatTheLastOneReached) {
  SpotLaneSweep spot;
  ASSERT_TRUE(spot.ok());
  auto& [mesh, graph, shape, sc, sources, nodes] = spot;
  // A limit that leaves most nodes out: the distance to the nearest tenth
  // of the nodes from the first source.
  double reach = 0;
  {
    QueryScratch full;
    ASSERT_OK(query_internal::SolveFieldLanes(*graph, shape, LaneFanLayout::kPacked, nullptr, full,
                                              sources, kInfinity, nullptr));
    std::vector<double> first;
    for (uint32_t u = 0; u < nodes; ++u) first.push_back(full.lane_dist[u].dist[0]);
    std::nth_element(first.begin(), first.begin() + nodes / 10, first.end());
    reach = first[nodes / 10];
    ASSERT_GT(reach, 0);
  }
  std::vector<query_internal::Endpoint> others;
  for (const SurfacePoint& p : MixedPoints(*mesh, 9)) {
    if (others.size() == 3) break;
    auto end = query_internal::JoinToGraph(*mesh, *graph, sc, p, false);
    ASSERT_OK(end);
    others.push_back(*std::move(end));
  }
  const std::function<bool()> cancel_at_once = [] { return true; };
  struct Step {
    const char* what;
    const std::vector<query_internal::Endpoint>* ends;
    double limit;
    const std::function<bool()>* cancelled;
  };
  const Step steps[] = {
      {"bounded", &sources, reach, nullptr},
      {"bounded, other sources and limit", &others, 2 * reach, nullptr},
      {"bounded again", &sources, reach, nullptr},
      {"cancelled", &others, reach, &cancel_at_once},
      {"bounded after a cancelled one", &sources, reach, nullptr},
      {"full", &others, kInfinity, nullptr},
      {"bounded after a full one", &sources, 2 * reach, nullptr},
  };
  for (const Step& step : steps) {
    SCOPED_TRACE(step.what);
    auto swept = query_internal::SolveFieldLanes(*graph, shape, LaneFanLayout::kPacked, nullptr, sc,
                                                 *step.ends, step.limit,
                                                 step.cancelled ? *step.cancelled : nullptr);
    if (step.cancelled) {
      EXPECT_EQ(swept.status().code(), absl::StatusCode::kCancelled);
      EXPECT_FALSE(sc.lanes_clear_but_reached);
      continue;
    }
    ASSERT_OK(swept);
    EXPECT_EQ(sc.lanes_clear_but_reached, step.limit < kInfinity);
    QueryScratch fresh;
    ASSERT_OK(query_internal::SolveFieldLanes(*graph, shape, LaneFanLayout::kPacked, nullptr, fresh,
                                              *step.ends, step.limit, nullptr));
    size_t finite = 0;
    for (uint32_t u = 0; u < nodes; ++u) {
      for (int k = 0; k < kFieldLanes; ++k) {
        ASSERT_EQ(fresh.lane_dist[u].dist[k], sc.lane_dist[u].dist[k])
            << "node " << u << " lane " << k;
        finite += std::isfinite(fresh.lane_dist[u].dist[k]);
      }
    }
    EXPECT_GT(finite, 0u);
    if (step.limit < kInfinity) {
      EXPECT_LT(finite, size_t{nodes} * kFieldLanes);
    } else {
      EXPECT_EQ(finite, size_t{nodes} * step.ends->size());
    }
  }
}

// Each x86 kernel this machine runs (AVX-512, AVX2) finds the same labels
// as the portable kernel, to the last bit, with fans packed or whole, the
// graph's edges or a compact copy, with and without a limit (their runs of edges may
// differ: each finds its own cover of the lanes' fans, so labels past a
// limit, which are bounds only, may differ too).
TEST(QueriesTest, LaneKernelsFindTheSameLabels) {
  using query_internal::LaneKernel;
  std::vector<LaneKernel> kernels;
  for (LaneKernel k : {LaneKernel::kAvx512, LaneKernel::kAvx2}) {
    if (query_internal::LaneKernelRuns(k)) kernels.push_back(k);
  }
  if (kernels.empty()) {
    GTEST_SKIP() << "this machine (or build) runs only the portable kernel";
  }
  SpotLaneSweep spot;
  ASSERT_TRUE(spot.ok());
  auto& [mesh, graph, shape, sc, sources, nodes] = spot;
  const std::optional<query_internal::CompactLaneEdges> compact =
      query_internal::CompactLaneEdges::Of(*graph);
  ASSERT_TRUE(compact.has_value());
  using Layout = std::pair<LaneFanLayout, const query_internal::CompactLaneEdges*>;
  for (LaneKernel kernel : kernels) {
    for (const auto& [layout, edges] :
         {Layout{LaneFanLayout::kPacked, nullptr}, Layout{LaneFanLayout::kWhole, nullptr},
          Layout{LaneFanLayout::kPacked, &*compact}}) {
      for (double limit : {kInfinity, 0.3}) {
        SCOPED_TRACE(absl::StrFormat("kernel %d, layout %d, compact edges %d, limit %g",
                                     int(kernel), int(layout), edges != nullptr, limit));
        auto fast = query_internal::SolveFieldLanes(*graph, shape, layout, edges, sc, sources,
                                                    limit, nullptr, kernel);
        ASSERT_OK(fast);
        const std::vector<LaneLabels> labels(sc.lane_dist.begin(), sc.lane_dist.begin() + nodes);
        auto portable = query_internal::SolveFieldLanes(*graph, shape, layout, edges, sc, sources,
                                                        limit, nullptr, LaneKernel::kPortable);
        ASSERT_OK(portable);
        EXPECT_GT(fast->relaxed, nodes);
        EXPECT_GT(portable->relaxed, nodes);
        // Labels past the limit are only bounds, and differ with the runs.
        auto read = [limit](double d) { return d <= limit ? d : kInfinity; };
        size_t within = 0;
        for (uint32_t u = 0; u < nodes; ++u) {
          for (int k = 0; k < kFieldLanes; ++k) {
            ASSERT_EQ(read(labels[u].dist[k]), read(sc.lane_dist[u].dist[k]))
                << "node " << u << " lane " << k;
            within += labels[u].dist[k] <= limit;
          }
        }
        // Both sides real: many labels within the limit, and with one, not all.
        EXPECT_GT(within, size_t{nodes} / 4);
        if (limit < kInfinity) {
          EXPECT_LT(within, size_t{nodes} * kFieldLanes);
        }
      }
    }
  }
}

// A radius keeps the entries within it, the same numbers as without one,
// and makes the rest +inf.
TEST(QueriesTest, MatrixWithinARadiusIsTheMatrixThresholded) {
  auto [mesh, graph] = SpotAndGraph(1e-3);
  ASSERT_NE(graph, nullptr);
  GeodesicEngine engine(mesh, graph);
  std::vector<SurfacePoint> points = MixedPoints(*mesh, 11);
  for (VertexId v = 0; v < mesh->num_vertices(); v += 97) points.push_back(SurfacePoint::Vertex(v));
  auto dense = engine.Matrix(points, points);
  ASSERT_OK(dense);
  std::vector<double> finite;
  for (double d : *dense) {
    if (std::isfinite(d)) finite.push_back(d);
  }
  ASSERT_FALSE(finite.empty());
  std::nth_element(finite.begin(), finite.begin() + finite.size() / 3, finite.end());
  MatrixOptions within;
  within.max_distance = finite[finite.size() / 3];
  auto near = engine.Matrix(points, points, within);
  ASSERT_OK(near);
  ASSERT_EQ(near->size(), dense->size());
  size_t kept = 0;
  for (size_t i = 0; i < dense->size(); ++i) {
    if ((*dense)[i] <= within.max_distance) {
      ++kept;
      EXPECT_EQ((*near)[i], (*dense)[i]) << i;
    } else {
      EXPECT_EQ((*near)[i], kInfinity) << i;
    }
  }
  EXPECT_GT(kept, points.size());
  EXPECT_LT(kept, dense->size());
}

// A sparse sink gets each row's entries within the radius, columns
// ascending, bit for bit the dense rows' (those also +inf past it): read
// from the nodes a sweep reached when sources and targets are vertices (a
// target listed twice included), else from whole rows.
TEST(QueriesTest, SparseRowsAreTheDenseRowsWithinTheRadius) {
  auto [mesh, graph] = SpotAndGraph(1e-3);
  ASSERT_NE(graph, nullptr);
  GeodesicEngine engine(mesh, graph);
  std::vector<SurfacePoint> vertices;
  for (VertexId v = 0; v < mesh->num_vertices(); ++v) vertices.push_back(SurfacePoint::Vertex(v));
  vertices.push_back(SurfacePoint::Vertex(3));
  std::vector<SurfacePoint> some_vertices;
  for (VertexId v = 0; v < mesh->num_vertices(); v += 23) {
    some_vertices.push_back(SurfacePoint::Vertex(v));
  }
  const std::vector<SurfacePoint> mixed = MixedPoints(*mesh, 5);
  auto rows_from_vertex = engine.Matrix({SurfacePoint::Vertex(0)}, vertices);
  ASSERT_OK(rows_from_vertex);
  std::vector<double> finite;
  for (double d : *rows_from_vertex) {
    if (std::isfinite(d)) finite.push_back(d);
  }
  ASSERT_GT(finite.size(), size_t{100});
  std::nth_element(finite.begin(), finite.begin() + finite.size() / 10, finite.end());
  MatrixOptions within;
  within.max_distance = finite[finite.size() / 10];

  const std::vector<std::pair<const std::vector<SurfacePoint>*, const std::vector<SurfacePoint>*>>
      cases = {{&some_vertices, &vertices}, {&mixed, &vertices}, {&some_vertices, &mixed}};
  for (const auto& [sources, targets] : cases) {
    SCOPED_TRACE(absl::StrFormat("%u sources, %u targets", sources->size(), targets->size()));
    auto dense = engine.Matrix(*sources, *targets, within);
    ASSERT_OK(dense);
    std::vector<std::vector<uint32_t>> columns(sources->size());
    std::vector<std::vector<double>> values(sources->size());
    MatrixRowSink sink;
    sink.sparse_row = [&](size_t i, absl::Span<const uint32_t> c, absl::Span<const double> v) {
      columns[i].assign(c.begin(), c.end());
      values[i].assign(v.begin(), v.end());
      return absl::OkStatus();
    };
    ASSERT_OK(engine.StreamMatrix(*sources, *targets, within, sink));
    size_t kept = 0;
    for (size_t i = 0; i < sources->size(); ++i) {
      std::vector<uint32_t> expected_columns;
      std::vector<uint64_t> expected_bits, bits;
      for (size_t j = 0; j < targets->size(); ++j) {
        const double d = (*dense)[i * targets->size() + j];
        if (d == kInfinity) continue;
        ASSERT_LE(d, within.max_distance);
        expected_columns.push_back(j);
        expected_bits.push_back(std::bit_cast<uint64_t>(d));
      }
      for (double d : values[i]) bits.push_back(std::bit_cast<uint64_t>(d));
      EXPECT_EQ(columns[i], expected_columns) << "row " << i;
      EXPECT_EQ(bits, expected_bits) << "row " << i;
      kept += expected_columns.size();
    }
    // Both sides real: entries kept, and not all of them.
    EXPECT_GT(kept, sources->size());
    EXPECT_LT(kept, sources->size() * targets->size() / 2);
  }
}

// Exact rows equal exact pairs and our exact engine's whole field, and are
// never above the graph's entries.
TEST(QueriesTest, ExactMatrixRowsEqualExactPairsOnSpot) {
  auto [mesh, graph] = SpotAndGraph(1e-2);
  ASSERT_NE(graph, nullptr);
  GeodesicEngine engine(mesh, graph);
  const std::vector<SurfacePoint> points = MixedPoints(*mesh, 7);
  ASSERT_FALSE(points.empty());
  MatrixOptions exact_rows;
  exact_rows.exact = true;
  auto exact = engine.Matrix(points, points, exact_rows);
  auto graph_only = engine.Matrix(points, points);
  ASSERT_OK(exact);
  ASSERT_OK(graph_only);
  ASSERT_EQ(exact->size(), points.size() * points.size());
  ExactGeodesic whole(*mesh);
  ExactOptions keep;
  keep.keep_windows = true;
  for (size_t i = 0; i < points.size(); ++i) {
    ASSERT_OK(whole.Distances(points[i], keep));
    for (size_t j = 0; j < points.size(); ++j) {
      const double got = (*exact)[i * points.size() + j];
      auto want = whole.DistanceTo(points[j]);
      ASSERT_OK(want);
      ASSERT_TRUE(std::isfinite(got) && std::isfinite(*want)) << i << "," << j;
      EXPECT_NEAR(got, *want, 1e-12 * std::max(*want, 1.0)) << i << "," << j;
      EXPECT_LE(got, (*graph_only)[i * points.size() + j] * (1 + 1e-12)) << i << "," << j;
      PairOptions pair;
      pair.exact = true;
      auto p = engine.Distance(points[i], points[j], pair);
      ASSERT_OK(p);
      EXPECT_NEAR(p->distance, got, 1e-12 * std::max(got, 1.0)) << i << "," << j;
    }
  }
}

// An exact pair past its memory limit fails with RESOURCE_EXHAUSTED naming
// the limit, and the engine answers the next pair as before.
TEST(QueriesTest, ExactPairsKeepToTheirMemoryLimit) {
  auto [mesh, graph] = SpotAndGraph(1e-2);
  ASSERT_NE(graph, nullptr);
  GeodesicEngine engine(mesh, graph);
  const SurfacePoint a = SurfacePoint::Vertex(0), b = SurfacePoint::Vertex(1500);
  PairOptions tight;
  tight.exact = true;
  tight.exact_max_bytes = 1;
  auto refused = engine.Distance(a, b, tight);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_THAT(std::string(refused.status().message()), ::testing::HasSubstr("over its limit"));
  PairOptions exact;
  exact.exact = true;
  auto answered = engine.Distance(a, b, exact);
  ASSERT_OK(answered);
  ExactGeodesic whole(*mesh);
  auto field = whole.Distances(a);
  ASSERT_OK(field);
  ASSERT_TRUE(std::isfinite((*field)[1500]) && std::isfinite(answered->distance));
  EXPECT_NEAR(answered->distance, (*field)[1500], 1e-12 * (*field)[1500]);
}

// A copy of `graph` whose every weight is `scale` times its own: what a
// graph file written by someone else might claim.
std::shared_ptr<const DggGraph> ScaledWeights(const DggGraph& graph, const Mesh& mesh,
                                              float scale) {
  DggGraphArrays a;
  a.offsets.assign(graph.offsets().begin(), graph.offsets().end());
  for (DggEdge e : graph.edges()) {
    e.weight *= scale;
    a.edges.push_back(e);
  }
  a.angles.assign(graph.angles().begin(), graph.angles().end());
  a.pseudo_points.assign(graph.pseudo_points().begin(), graph.pseudo_points().end());
  a.node_of_vertex.assign(graph.node_of_vertex().begin(), graph.node_of_vertex().end());
  a.vertex_of_node.assign(graph.vertex_of_node().begin(), graph.vertex_of_node().end());
  return DggGraphBuilder::FromArrays(std::move(a), graph.num_nodes(), graph.num_mesh_vertices(),
                                     graph.params(), MeshFingerprint(mesh));
}

// Exact answers do not trust the graph: a graph whose weights are too short
// bounds the exact propagation below the exact distance, and the pair and
// the matrix row are still the exact ones. Halved weights leave the vertex
// target within the retry at twice the bound; quartered, it takes the
// unbounded run.
class ShortWeightsTest : public ::testing::TestWithParam<float> {};

TEST_P(ShortWeightsTest, ExactPairsAndRowsStayExact) {
  auto [mesh, graph] = SpotAndGraph(1e-2);
  ASSERT_NE(graph, nullptr);
  GeodesicEngine engine(mesh, ScaledWeights(*graph, *mesh, GetParam()));
  const SurfacePoint a = SurfacePoint::Vertex(0);
  const std::vector<SurfacePoint> targets = {SurfacePoint::Vertex(1500),
                                             SurfacePoint::Face(100, 0.2, 0.3, 0.5)};
  ExactGeodesic whole(*mesh);
  ExactOptions keep;
  keep.keep_windows = true;
  ASSERT_OK(whole.Distances(a, keep));
  MatrixOptions exact_rows;
  exact_rows.exact = true;
  auto row = engine.Matrix({&a, 1}, targets, exact_rows);
  ASSERT_OK(row);
  ASSERT_EQ(row->size(), targets.size());
  for (size_t j = 0; j < targets.size(); ++j) {
    auto want = whole.DistanceTo(targets[j]);
    ASSERT_OK(want);
    auto graph_only = engine.Distance(a, targets[j], PairOptions{});
    ASSERT_OK(graph_only);
    ASSERT_TRUE(std::isfinite(*want) && std::isfinite(graph_only->distance)) << j;
    // The scaled graph does answer below the exact distance.
    ASSERT_LT(graph_only->distance, *want * 0.9) << j;
    PairOptions exact;
    exact.exact = true;
    exact.want_path = true;
    auto pair = engine.Distance(a, targets[j], exact);
    ASSERT_OK(pair);
    EXPECT_TRUE(pair->exact);
    EXPECT_NEAR(pair->distance, *want, 1e-12 * *want) << j;
    ASSERT_TRUE(pair->path.has_value()) << j;
    EXPECT_NEAR(pair->path->length, *want, 1e-9 * *want) << j;
    EXPECT_NEAR((*row)[j], *want, 1e-12 * *want) << j;
  }
}
INSTANTIATE_TEST_SUITE_P(HalfAndQuarter, ShortWeightsTest, ::testing::Values(0.5f, 0.25f));

// Entries on the independent solver's exact pairs: within the accuracy
// contract (mean 0.3 eps, max 1.5 eps), never below exact, and equal to the
// pair's distance.
class MatrixPairsTest : public ::testing::TestWithParam<std::string> {};

TEST_P(MatrixPairsTest, WithinEpsilonOfExactPairs) {
  ASSERT_TRUE(SharedDataAvailable()) << "missing " << SharedPath("meshes/MANIFEST.md");
  const std::string name = GetParam();
  auto loaded = LoadMesh(testing::SharedMeshPath(name));
  ASSERT_OK(loaded);
  auto mesh = std::make_shared<const Mesh>(std::move(loaded).value());
  const double eps = 1e-2;
  DggBuildOptions options;
  options.params.epsilon = eps;
  auto graph = BuildDgg(*mesh, options);
  ASSERT_OK(graph);
  GeodesicEngine engine(mesh, *graph);
  const std::vector<Pair> pairs = ReadPairs(*mesh, name);
  ASSERT_GE(pairs.size(), 100u);
  // The pairs share their first points: one row per first point, one column
  // per pair.
  std::vector<SurfacePoint> sources, targets;
  std::vector<size_t> row_of;
  for (const Pair& p : pairs) {
    auto same = [&](const SurfacePoint& q) {
      return FormatSurfacePoint(q) == FormatSurfacePoint(p.a);
    };
    auto it = std::find_if(sources.begin(), sources.end(), same);
    row_of.push_back(it - sources.begin());
    if (it == sources.end()) sources.push_back(p.a);
    targets.push_back(p.b);
  }
  auto m = engine.Matrix(sources, targets);
  ASSERT_OK(m);
  double sum = 0;
  size_t count = 0;
  for (size_t k = 0; k < pairs.size(); ++k) {
    const double entry = (*m)[row_of[k] * targets.size() + k];
    if (pairs[k].exact == kInfinity) {
      EXPECT_EQ(entry, kInfinity) << "pair " << k;
      continue;
    }
    if (pairs[k].exact == 0) {
      EXPECT_EQ(entry, 0) << "pair " << k;
      continue;
    }
    const double rel = (entry - pairs[k].exact) / pairs[k].exact;
    EXPECT_GE(rel, -1e-9) << "pair " << k;
    EXPECT_LE(rel, 1.5 * eps) << "pair " << k;
    sum += rel;
    ++count;
    auto pair = engine.Distance(pairs[k].a, pairs[k].b, {});
    ASSERT_OK(pair);
    EXPECT_EQ(entry, pair->distance) << "pair " << k;
  }
  ASSERT_GT(count, 0u);
  EXPECT_LT(sum / count, 0.3 * eps);
}

INSTANTIATE_TEST_SUITE_P(SharedMeshes, MatrixPairsTest,
                         ::testing::Values("armadillo", "bunny", "camelhead", "fertility"));

// Dijkstra's heap: nodes come out in key order, each once, with the
// smallest key it was given, whatever the order of pushes and decreases.
TEST(NodeHeapTest, PopsEachNodeOnceInKeyOrder) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> key(0, 100);
  for (int round = 0; round < 20; ++round) {
    const uint32_t n = 1 + rng() % 300;
    NodeHeap heap;
    heap.Reset(n);
    std::vector<double> best(n, INFINITY);
    for (int k = 0; k < 3 * static_cast<int>(n); ++k) {
      const uint32_t v = rng() % n;
      const double d = key(rng);
      heap.Push(v, d);
      best[v] = std::min(best[v], d);
    }
    std::vector<bool> seen(n, false);
    double last = -1;
    while (!heap.empty()) {
      const uint32_t v = heap.top();
      ASSERT_FALSE(seen[v]) << "node " << v << " popped twice";
      seen[v] = true;
      EXPECT_EQ(heap.top_key(), best[v]);
      EXPECT_GE(heap.top_key(), last);
      last = heap.top_key();
      heap.Pop();
    }
    for (uint32_t v = 0; v < n; ++v) EXPECT_EQ(seen[v], best[v] < INFINITY) << "node " << v;
  }
}

}  // namespace
}  // namespace geodesic

namespace geodesic {
namespace {

// Farthest-point sampling against its definition, recomputed with
// multi-source fields from the samples chosen so far.
TEST(SamplePointsTest, EachPointIsTheFarthestFromThoseBefore) {
  auto loaded = LoadMesh(testing::SourcePath("data/spot.obj"));
  ASSERT_OK(loaded);
  auto mesh = std::make_shared<const Mesh>(std::move(loaded).value());
  DggBuildOptions options;
  options.params.epsilon = 1e-2;
  auto graph = BuildDgg(*mesh, options);
  ASSERT_OK(graph);
  GeodesicEngine engine(mesh, *graph);
  SampleOptions sample_options;
  sample_options.seed = 5;
  auto sample = engine.SamplePoints(12, sample_options);
  ASSERT_OK(sample);
  ASSERT_EQ(sample->vertices.size(), 12u);
  std::vector<SurfacePoint> chosen;
  double last_radius = kInfinity;
  for (size_t i = 1; i <= sample->vertices.size(); ++i) {
    chosen.push_back(SurfacePoint::Vertex(sample->vertices[i - 1]));
    auto field = engine.Field(chosen, {});
    ASSERT_OK(field);
    const double radius = *std::max_element(field->distance.begin(), field->distance.end());
    EXPECT_LE(radius, last_radius);
    last_radius = radius;
    if (i < sample->vertices.size()) {
      EXPECT_EQ(field->distance[sample->vertices[i]], radius) << "sample " << i;
    } else {
      EXPECT_EQ(sample->covering_radius, radius);
    }
  }
  // One seed, one sampling; another seed starts elsewhere.
  auto again = engine.SamplePoints(12, sample_options);
  ASSERT_OK(again);
  EXPECT_EQ(again->vertices, sample->vertices);
  sample_options.seed = 6;
  auto other = engine.SamplePoints(12, sample_options);
  ASSERT_OK(other);
  EXPECT_NE(other->vertices[0], sample->vertices[0]);
  EXPECT_EQ(engine.SamplePoints(0, {}).status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(engine.SamplePoints(mesh->num_vertices() + 1, {}).status().code(),
            absl::StatusCode::kInvalidArgument);
}

// Two separate squares: the second sample goes to the component the first
// did not reach, and only then is the radius finite.
TEST(SamplePointsTest, EveryComponentGetsASampleAndAllVerticesCanBeChosen) {
  TriangleSoup soup;
  for (double x0 : {0.0, 10.0}) {
    const VertexId base = soup.positions.size();
    soup.positions.insert(soup.positions.end(),
                          {{x0, 0, 0}, {x0 + 1, 0, 0}, {x0 + 1, 1, 0}, {x0, 1, 0}});
    soup.triangles.push_back({base, base + 1, base + 2});
    soup.triangles.push_back({base, base + 2, base + 3});
  }
  soup.positions.push_back({5, 5, 5});  // used by no face: not on the surface
  auto mesh = std::make_shared<const Mesh>(testing::MustBuild(soup));
  DggBuildOptions options;
  options.params.epsilon = 1e-2;
  auto graph = BuildDgg(*mesh, options);
  ASSERT_OK(graph);
  GeodesicEngine engine(mesh, *graph);
  auto one = engine.SamplePoints(1, {});
  ASSERT_OK(one);
  EXPECT_EQ(one->covering_radius, kInfinity);
  auto two = engine.SamplePoints(2, {});
  ASSERT_OK(two);
  EXPECT_NE(two->vertices[0] / 4, two->vertices[1] / 4);
  EXPECT_NEAR(two->covering_radius, std::sqrt(2.0), 1e-6);
  auto all = engine.SamplePoints(8, {});
  ASSERT_OK(all);
  std::vector<VertexId> sorted = all->vertices;
  std::sort(sorted.begin(), sorted.end());
  EXPECT_EQ(sorted, (std::vector<VertexId>{0, 1, 2, 3, 4, 5, 6, 7}));
  EXPECT_EQ(all->covering_radius, 0);
  EXPECT_EQ(engine.SamplePoints(9, {}).status().code(), absl::StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace geodesic
