#include "core/query/certified_graph.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include "absl/strings/str_format.h"
#include "core/base/status.h"
#include "core/query/accuracy_check.h"
#include "core/query/build_dgg.h"

namespace geodesic {
namespace {

// The share of a build-and-check that progress gives the build; the check
// takes the rest. Only for the progress fraction.
constexpr double kBuildShare = 0.5;

// A rebuild at most quarters epsilon: cost grows quickly as epsilon shrinks,
// and a graph that far off means something other than epsilon is at fault.
constexpr double kCertifyMinRebuildScale = 0.25;

// One check's sources together.
struct Measured {
  double max_error = 0;
  double mean_error = 0;
  const SourceCheck* unsound = nullptr;  // the first with an inequality broken
};

Measured Summarize(const std::vector<SourceCheck>& checks) {
  Measured m;
  double total = 0;
  uint64_t compared = 0;
  for (const SourceCheck& c : checks) {
    const FieldComparison& f = c.comparison;
    if (f.compared) m.max_error = std::max(m.max_error, f.max_error);
    total += f.mean_error * f.compared;
    compared += f.compared;
    if (!m.unsound && !f.sound()) m.unsound = &c;
  }
  m.mean_error = compared ? total / compared : 0;
  return m;
}

std::string Violation(const SourceCheck& c) {
  const FieldComparison& f = c.comparison;
  return absl::StrFormat(
      "certifying: the graph is unsound from source %s (%d vertices below exact, %d only the "
      "exact engine reaches, %d only the graph reaches, %d exact below the straight line%s)",
      FormatSurfacePoint(c.source), f.below_exact, f.graph_unreached, f.exact_unreached,
      f.below_straight, f.source_nonzero ? ", source not at 0" : "");
}

// Cancellation and progress shared by the builds and checks of one call.
class CertifyControl {
 public:
  explicit CertifyControl(const CertifyOptions& options) : options_(options) {}

  bool stopped() {
    if (stop_) return true;
    if (options_.cancelled && options_.cancelled()) stop_ = true;
    return stop_;
  }
  // Progress of build `build` (0-based); false once cancelled.
  bool Report(uint32_t build, std::string_view phase, double fraction) {
    if (stopped()) return false;
    if (options_.progress && !options_.progress(build + 1, phase, fraction)) stop_ = true;
    return !stop_;
  }

 private:
  const CertifyOptions& options_;
  std::atomic<bool> stop_{false};
};

absl::StatusOr<std::vector<SourceCheck>> CheckBuild(std::shared_ptr<const Mesh> mesh,
                                                    std::shared_ptr<const DggGraph> graph,
                                                    const CertifyOptions& options, uint32_t build,
                                                    CertifyControl& control) {
  std::vector<SurfacePoint> sources;
  for (VertexId v : RandomSurfaceVertices(*mesh, options.sources, options.seed + build)) {
    sources.push_back(SurfacePoint::Vertex(v));
  }
  if (sources.empty()) {
    return absl::FailedPreconditionError("certifying: the mesh has no vertex on a face");
  }
  std::atomic<size_t> done{0};
  AccuracyCheckOptions check;
  check.threads = options.build.threads;
  check.cancelled = [&control] { return control.stopped(); };
  check.source_done = [&] {
    const double fraction = double(++done) / sources.size();
    control.Report(build, "check", kBuildShare + (1 - kBuildShare) * fraction);
  };
  return CheckAgainstExact(std::move(mesh), std::move(graph), sources, check);
}

absl::Status ValidateCertify(double max_error, const CertifyOptions& options) {
  if (!(max_error > 0 && max_error < 1)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("max error bound must be in (0, 1), got %g", max_error));
  }
  if (options.sources == 0) {
    return absl::InvalidArgumentError("certifying needs at least one source");
  }
  if (options.max_builds == 0) {
    return absl::InvalidArgumentError("certifying needs at least one build");
  }
  return absl::OkStatus();
}

absl::Status Missed(double max_error, uint32_t builds, double best_max, double best_epsilon) {
  return absl::FailedPreconditionError(absl::StrFormat(
      "no graph kept the max error bound %g: after %d builds the best measured max error was %g "
      "(at eps %g), above the %g a certificate needs (the bound over the safety factor %g)",
      max_error, builds, best_max, best_epsilon, max_error / kCertifySafetyFactor,
      kCertifySafetyFactor));
}

}  // namespace

double NextCertifyEpsilon(double max_error, double epsilon, double measured_max) {
  if (!(measured_max > 0)) return kCertifyEpsilonFactor * max_error;
  const double wanted = max_error / kCertifySafetyFactor / measured_max * kCertifyRebuildMargin;
  return epsilon * std::clamp(wanted, kCertifyMinRebuildScale, kCertifyMaxRebuildScale);
}

// Build, check, and rebuild tighter until the check's maximum is within the
// bound over the safety factor (certified_graph.h).
absl::StatusOr<CertifiedGraph> BuildCertifiedGraph(std::shared_ptr<const Mesh> mesh,
                                                   double max_error,
                                                   const CertifyOptions& options) {
  RETURN_IF_ERROR(ValidateCertify(max_error, options));
  CertifyControl control(options);
  const auto cancelled = [] { return absl::CancelledError("certified build cancelled"); };
  double epsilon = NextCertifyEpsilon(max_error, 0, 0);
  double best_max = std::numeric_limits<double>::infinity(), best_epsilon = epsilon;
  for (uint32_t build = 0; build < options.max_builds; ++build) {
    DggBuildOptions build_options = options.build;
    build_options.params.epsilon = epsilon;
    build_options.progress = [&](std::string_view phase, double fraction) {
      return control.Report(build, phase, kBuildShare * fraction);
    };
    CertifiedGraph result;
    auto graph = BuildDgg(*mesh, build_options, &result.stats);
    if (control.stopped()) return cancelled();
    if (!graph.ok()) return graph.status();
    auto checks = CheckBuild(mesh, *graph, options, build, control);
    if (control.stopped()) return cancelled();
    if (!checks.ok()) return checks.status();
    const Measured m = Summarize(*checks);
    if (m.unsound) return absl::InternalError(Violation(*m.unsound));
    if (m.max_error < best_max) std::tie(best_max, best_epsilon) = std::pair(m.max_error, epsilon);
    if (m.max_error <= max_error / kCertifySafetyFactor) {
      result.graph = *std::move(graph);
      result.certificate = {max_error,
                            epsilon,
                            m.max_error,
                            m.mean_error,
                            static_cast<uint32_t>(checks->size()),
                            options.seed + build,
                            true,
                            build + 1};
      return result;
    }
    epsilon = NextCertifyEpsilon(max_error, epsilon, m.max_error);
  }
  return Missed(max_error, options.max_builds, best_max, best_epsilon);
}

}  // namespace geodesic
