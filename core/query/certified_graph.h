// Graphs asked for by the error they must keep, with a measured certificate.
//
// A DGG built at epsilon keeps most errors well below epsilon but, through
// corner routes that compound (bench/notes.md, "ε as a hard bound"), lets
// its largest ones pass it. A certified graph turns a bound on the error
// into a build: it picks the build epsilon from the bound with a margin,
// builds, measures the graph against the exact engine from seeded random
// vertex sources at every vertex (core/query/accuracy_check.h), and only
// publishes a graph whose measured maximum stays below the bound by a
// second margin, the one that covers the sources not measured. A graph
// that misses is rebuilt at a smaller epsilon.
#ifndef GEODESIC_CORE_QUERY_CERTIFIED_GRAPH_H_
#define GEODESIC_CORE_QUERY_CERTIFIED_GRAPH_H_

#include <cstdint>
#include <functional>
#include <memory>
#include <string_view>

#include "absl/status/statusor.h"
#include "core/dgg/dgg_build.h"
#include "core/dgg/dgg_graph.h"
#include "core/mesh/mesh.h"

namespace geodesic {

// The build epsilon of the first build, as a fraction of the bound. A
// graph's largest error over all its sources passes its own epsilon on most
// meshes, by a factor that depends on the mesh and falls in steps, not
// smoothly, as epsilon shrinks (bench/notes.md, "ε as a hard bound"). This
// fraction keeps the largest such factor measured on the shared meshes,
// over many sources, well inside the bound: on a mesh like those the first
// graph already keeps the bound before it is checked, and passes its check
// without a rebuild. The check is then the second, independent margin, for
// meshes unlike any measured. Degree grows like 1/sqrt(epsilon), so this is
// what certification costs over a plain graph.
inline constexpr double kCertifyEpsilonFactor = 0.4;

// A graph is certified when its measured maximum is at most the bound
// divided by this. A check from a few sources sees the largest error of
// those sources only; the largest over every source is higher. How much
// higher bench/certify_margins.py measures, as the chance that a random
// draw of the checked number of sources sees less than the largest over
// many sources divided by a factor. With the default sources that chance
// was small at this factor on the mesh whose worst errors come from fewest
// sources, and nil on most: a false certificate needs it and a mesh whose
// errors pass the first build's margin at once. Fewer sources than the
// default weaken this margin quickly (bench/notes.md, "Certified graphs").
inline constexpr double kCertifySafetyFactor = 1.5;

// A rebuild's epsilon is scaled by (bound / safety) / measured maximum
// times this, and by at most kCertifyMaxRebuildScale: maxima fall in steps
// as epsilon shrinks, so the scaled epsilon alone may land on the same step.
inline constexpr double kCertifyRebuildMargin = 0.9;
inline constexpr double kCertifyMaxRebuildScale = 0.8;

// What was measured of a certified graph. Errors are relative,
// (graph - exact) / exact, over every vertex from every source.
struct GraphCertificate {
  double max_error_bound = 0;  // what was asked for
  double epsilon = 0;          // the graph's build epsilon
  double measured_max_error = 0;
  double measured_mean_error = 0;
  // Random vertex sources of the last check (RandomSurfaceVertices with
  // `seed`): `geodesicd check --sources N --seed S` repeats it.
  uint32_t sources = 0;
  uint64_t seed = 0;
  // No inequality that must hold whatever the mesh was broken (graph below
  // exact, a vertex only one engine reaches, ...). A certified graph is
  // always sound; an unsound check fails the certification instead.
  bool sound = false;
  uint32_t builds = 0;  // graphs built, the published one included
};

struct CertifyOptions {
  // How to build: every field but params.epsilon, which the bound sets, and
  // progress, which the field below replaces. build.threads also runs the
  // check.
  DggBuildOptions build;
  uint32_t sources = 16;  // random vertex sources of each check
  // Build i (0-based) is checked from the sources of seed + i, so that a
  // rebuild is not judged on the sources that rejected the graph before it.
  uint64_t seed = 1;
  uint32_t max_builds = 3;
  // Called now and then from any thread: the build (1-based), the phase
  // (the build's phases, then "check") and the fraction of that build's
  // build-and-check done, in [0, 1]. Returning false cancels (CANCELLED).
  std::function<bool(uint32_t build, std::string_view phase, double fraction)> progress;
  // Polled from any thread during builds and checks; returning true
  // cancels (CANCELLED).
  std::function<bool()> cancelled;
};

struct CertifiedGraph {
  std::shared_ptr<const DggGraph> graph;
  GraphCertificate certificate;
  DggBuildStats stats;  // of the published graph's build
};

// Builds a graph of `mesh` certified to keep relative errors at most
// `max_error`. INVALID_ARGUMENT for a bound outside (0, 1), or sources 0;
// FAILED_PRECONDITION naming the bound, the best measured maximum and its
// epsilon when max_builds graphs all miss; INTERNAL naming the source when
// a check finds the graph unsound; CANCELLED; and the build's own errors.
absl::StatusOr<CertifiedGraph> BuildCertifiedGraph(std::shared_ptr<const Mesh> mesh,
                                                   double max_error, const CertifyOptions& options);

// The epsilon of the next build after one at `epsilon` measured
// `measured_max` against `max_error`: the first build's when measured_max
// is 0.
double NextCertifyEpsilon(double max_error, double epsilon, double measured_max);

}  // namespace geodesic

#endif  // GEODESIC_CORE_QUERY_CERTIFIED_GRAPH_H_
