// The fan of a directed DGG edge (section 5.1.2 of the DGG paper): the
// outgoing edges at the edge's far end that can continue a path arriving
// along it. The graph stores, per edge, the range its shortest paths can
// continue on (core/dgg/fans.cc); redundant-edge pruning asks the geometric
// question below, whether a direction continues a geodesic.
#ifndef GEODESIC_CORE_DGG_FAN_H_
#define GEODESIC_CORE_DGG_FAN_H_

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numbers>
#include <span>

#include "core/base/vec.h"
#include "core/dgg/dgg_graph.h"

namespace geodesic {

// Half-width of a fan in multiples of sqrt(epsilon). A graph path that
// approximates a geodesic turns by about arcsin(sqrt(eps)) at a relay.
inline constexpr double kFanWidth = 4.0;

// The turns that continue a geodesic, in raw radians of the node's cone:
// (b - arrival) mod period in [lo, hi].
struct FanTurns {
  double lo, hi;
};
inline FanTurns ContinuingTurns(double period, double epsilon, double width_scale = 1.0) {
  const double width = width_scale * kFanWidth * std::sqrt(epsilon);
  return {std::min(std::numbers::pi, period - std::numbers::pi) - width,
          std::max(std::numbers::pi, period - std::numbers::pi) + width};
}

// Whether leaving a node at angle `departure` continues a geodesic that
// arrived along the direction `arrival` (both normalised), with the fan's
// half-width scaled by `width_scale`.
inline bool InFan(double arrival, double departure, double period, bool boundary, double epsilon,
                  double width_scale = 1.0) {
  constexpr double kTwoPi = 2 * std::numbers::pi;
  if (boundary) return true;
  const FanTurns turns = ContinuingTurns(period, epsilon, width_scale);
  if (turns.hi - turns.lo >= period) return true;
  const double turn = WrapAngle((departure - arrival) * (period / kTwoPi), period);
  return turn >= turns.lo && turn <= turns.hi;
}

// A turn u -> v -> w is left out of the fan of u -> v only when some path
// from u to w is shorter than |uv| + |vw| by at least this factor, so that
// the rounding of a search's sums cannot make a left-out turn the only
// shortest way on.
inline constexpr double kStrictlyShorter = 1 - 1e-9;

// The shortest circular range of `degree` indices holding every index in
// `kept` (sorted): it starts after the widest gap.
inline FanRange CircularHull(std::span<const uint32_t> kept, uint32_t degree) {
  if (kept.empty()) return {};
  uint32_t widest = kept.front() + degree - kept.back(), start = kept.front();
  for (size_t q = 1; q < kept.size(); ++q) {
    if (kept[q] - kept[q - 1] > widest) {
      widest = kept[q] - kept[q - 1];
      start = kept[q];
    }
  }
  return {start, degree - widest + 1};
}

}  // namespace geodesic

#endif  // GEODESIC_CORE_DGG_FAN_H_
