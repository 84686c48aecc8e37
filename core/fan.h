// The fan of a directed DGG edge (section 5.1.2 of the DGG paper): the
// outgoing edges at the edge's far end that can continue a geodesic arriving
// along it. Shared by graph construction (stored fans) and by queries (fans
// of temporary edges from points inside faces).
#ifndef GEODESIC_CORE_FAN_H_
#define GEODESIC_CORE_FAN_H_

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numbers>
#include <span>

#include "core/vec.h"

namespace geodesic {

// Half-width of a fan in multiples of sqrt(epsilon). A graph path that
// approximates a geodesic turns by about arcsin(sqrt(eps)) at a relay; the
// margin keeps the labels a fan-restricted search leaves too long (and its
// final check of every edge must repair) to a few per thousand nodes.
inline constexpr double kFanWidth = 4.0;

struct FanRange {
  uint32_t begin = 0;  // local index into the node's angle-sorted edges
  uint32_t count = 0;  // edges, wrapping around the end of the list
};

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

// `angles`: the node's outgoing edge angles, sorted, normalised to [0, 2*pi).
// `arrival`: normalised angle at the node of the direction back along the
// arriving edge. `period`: the node's cone angle (2*pi for points inside
// faces). Boundary nodes get every edge: geodesics wrap around boundary
// corners in any direction.
inline FanRange ComputeFan(std::span<const float> angles, double arrival, double period,
                           bool boundary, double epsilon) {
  constexpr double kTwoPi = 2 * std::numbers::pi;
  const uint32_t degree = angles.size();
  if (degree == 0 || boundary) return {0, degree};
  // Continuing directions b satisfy (b - arrival) mod period in
  // [min(pi, period - pi) - w, max(pi, period - pi) + w] radians of the cone.
  const FanTurns turns = ContinuingTurns(period, epsilon);
  const double scale = kTwoPi / period;
  const double span = (turns.hi - turns.lo) * scale;
  if (span >= kTwoPi) return {0, degree};
  const double lo = WrapAngle(arrival + turns.lo * scale, kTwoPi);
  const uint32_t begin =
      static_cast<uint32_t>(std::lower_bound(angles.begin(), angles.end(), lo) - angles.begin()) %
      degree;
  uint32_t count = 0;
  for (; count < degree; ++count) {
    double d = angles[(begin + count) % degree] - lo;
    if (d < 0) d += kTwoPi;
    if (d > span) break;
  }
  return {begin, count};
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

}  // namespace geodesic

#endif  // GEODESIC_CORE_FAN_H_
