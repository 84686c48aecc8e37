// How much an exact pair's region shrinks with each lower bound on the
// distance to its second point: the straight line alone, exact landmarks
// (core/query/exact_landmarks.h) by count, and a perfect bound (the exact
// field from the second point itself), which no bound can beat.
//
//   exact_bounds_bench MESH [PAIRS=30] [SLACK=2e-4]
//
// Random vertex pairs (seed 7); each propagation is bounded by the exact
// distance times 1 + SLACK, standing in for a graph's answer. Prints the
// p50 and p90 windows created and milliseconds per bound, one thread.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <string>
#include <vector>

#include "core/exact/exact_geodesic.h"
#include "core/mesh/mesh_io.h"
#include "core/query/exact_landmarks.h"

namespace geodesic {
namespace {

// The exact field from the goal: the tightest valid bound there is.
class PerfectFloor final : public GoalFloor {
 public:
  explicit PerfectFloor(const std::vector<double>& field) : field_(field) {}
  double At(VertexId v) const override { return field_[v]; }

 private:
  const std::vector<double>& field_;
};

// Farthest-point sampling on exact fields: each landmark the vertex farthest
// from those before, from vertex 0's farthest.
std::vector<VertexId> SpreadByExactFields(const Mesh& mesh, ExactGeodesic& exact, int count) {
  std::vector<double> nearest(mesh.num_vertices(), INFINITY);
  std::vector<VertexId> out;
  VertexId next = 0;
  for (int k = 0; k <= count; ++k) {
    const std::vector<double> field = *exact.Distances(SurfacePoint::Vertex(next));
    if (k > 0) out.push_back(next);
    for (size_t v = 0; v < field.size(); ++v) {
      nearest[v] = k == 0 ? field[v] : std::min(nearest[v], field[v]);
      if (!std::isfinite(nearest[v])) nearest[v] = -1;
    }
    next = std::max_element(nearest.begin(), nearest.end()) - nearest.begin();
  }
  return out;
}

double Percentile(std::vector<double> v, double q) {
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<size_t>(q * v.size()))];
}

int Run(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: exact_bounds_bench MESH [PAIRS] [SLACK]\n");
    return 2;
  }
  auto loaded = LoadMesh(argv[1]);
  if (!loaded.ok()) {
    std::fprintf(stderr, "%s\n", std::string(loaded.status().message()).c_str());
    return 1;
  }
  const Mesh& mesh = *loaded;
  const int pairs = argc > 2 ? std::atoi(argv[2]) : 30;
  const double slack = argc > 3 ? std::atof(argv[3]) : 2e-4;
  const FaceFrames frames(mesh);
  ExactGeodesic exact(mesh, &frames);
  const std::vector<VertexId> spread = SpreadByExactFields(mesh, exact, 16);
  const std::vector<int> counts = {4, 8, 16};
  std::vector<std::unique_ptr<const ExactLandmarks>> landmarks;
  for (int k : counts) {
    landmarks.push_back(*ExactLandmarks::Compute(mesh, {spread.data(), static_cast<size_t>(k)}));
  }
  const int kinds = 2 + counts.size();  // straight, landmarks..., perfect
  std::vector<std::vector<double>> windows(kinds), ms(kinds);
  std::mt19937 rng(7);
  std::uniform_int_distribution<VertexId> pick(0, mesh.num_vertices() - 1);
  for (int p = 0; p < pairs; ++p) {
    const VertexId a = pick(rng), b = pick(rng);
    const std::vector<double> from_b = *exact.Distances(SurfacePoint::Vertex(b));
    const double d = from_b[a];
    if (!std::isfinite(d) || d == 0) continue;
    const PerfectFloor perfect(from_b);
    for (int kind = 0; kind < kinds; ++kind) {
      ExactOptions options;
      options.max_distance = d * (1 + slack);
      options.goal = mesh.position(b);
      std::optional<ExactLandmarks::Floor> floor;
      if (kind == kinds - 1) {
        options.goal_floor = &perfect;
      } else if (kind > 0) {
        floor = landmarks[kind - 1]->FloorFor(mesh, SurfacePoint::Vertex(b));
        options.goal_floor = &*floor;
      }
      const auto start = std::chrono::steady_clock::now();
      auto field = exact.Distances(SurfacePoint::Vertex(a), options);
      const double spent =
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
              .count();
      if (!field.ok() || std::abs((*field)[b] - d) > 1e-12 * d) {
        std::fprintf(stderr, "pair %d, bound %d: not the exact distance\n", p, kind);
        return 1;
      }
      windows[kind].push_back(exact.stats().windows_created);
      ms[kind].push_back(spent);
    }
  }
  std::printf(
      "| bound | windows p50 | windows p90 | ms p50 | ms p90 |\n|---|---:|---:|---:|---:|\n");
  for (int kind = 0; kind < kinds; ++kind) {
    const std::string name = kind == 0           ? "straight line"
                             : kind == kinds - 1 ? "perfect (exact field from the goal)"
                                                 : std::to_string(counts[kind - 1]) + " landmarks";
    std::printf("| %s | %.0f | %.0f | %.2f | %.2f |\n", name.c_str(),
                Percentile(windows[kind], 0.5), Percentile(windows[kind], 0.9),
                Percentile(ms[kind], 0.5), Percentile(ms[kind], 0.9));
  }
  return 0;
}

}  // namespace
}  // namespace geodesic

int main(int argc, char** argv) { return geodesic::Run(argc, argv); }
