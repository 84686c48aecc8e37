#include "server/graphs/graph_key.h"

namespace geodesic::server {

const char* GraphStateName(GraphState s) {
  switch (s) {
    case GraphState::kQueued:
      return "queued";
    case GraphState::kLoading:
      return "loading";
    case GraphState::kBuilding:
      return "building";
    case GraphState::kPersisting:
      return "persisting";
    case GraphState::kReady:
      return "ready";
    case GraphState::kFailed:
      return "failed";
    case GraphState::kCancelled:
      return "cancelled";
    case GraphState::kEvicted:
      return "evicted";
  }
  return "?";
}

bool LegalTransition(GraphState from, GraphState to) {
  constexpr bool Q = true, _ = false;
  // Rows: from; columns: to, in declaration order (queued, loading,
  // building, persisting, ready, failed, cancelled, evicted).
  static constexpr bool kLegal[kGraphStateCount][kGraphStateCount] = {
      /* queued     */ {_, Q, Q, _, _, _, Q, _},
      /* loading    */ {_, _, Q, _, Q, Q, Q, _},
      /* building   */ {_, _, _, Q, Q, Q, Q, _},
      /* persisting */ {_, _, _, _, Q, Q, Q, _},
      /* ready      */ {_, _, _, _, _, _, _, Q},
      /* failed     */ {Q, _, _, _, _, _, _, _},
      /* cancelled  */ {Q, _, _, _, _, _, _, _},
      /* evicted    */ {Q, _, _, _, _, _, _, _},
  };
  return kLegal[static_cast<int>(from)][static_cast<int>(to)];
}

double CertifiedKeyEpsilon(double max_error) { return NextCertifyEpsilon(max_error, 0, 0); }

}  // namespace geodesic::server
