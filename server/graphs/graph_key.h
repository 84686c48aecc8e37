// What names a graph of the daemon and what is known of it: its key (mesh
// and build record), its state and the table of legal moves between states,
// and its status as the API reports it. No cache here: the API's
// conversions and the config file read these without the cache.
#ifndef GEODESIC_SERVER_GRAPHS_GRAPH_KEY_H_
#define GEODESIC_SERVER_GRAPHS_GRAPH_KEY_H_

#include <cstdint>
#include <optional>
#include <string>

#include "core/dgg/dgg_build.h"
#include "core/query/certified_graph.h"

namespace geodesic::server {

enum class GraphState {
  kQueued,
  kLoading,  // mapping and validating the file in --graph-dir
  kBuilding,
  kPersisting,  // writing the built graph to --graph-dir
  kReady,
  kFailed,
  kCancelled,
  kEvicted,
};
inline constexpr int kGraphStateCount = 8;
const char* GraphStateName(GraphState s);
// Whether the table of legal moves allows `from` -> `to`.
bool LegalTransition(GraphState from, GraphState to);

// The phase of a queued graph whose file another replica is building.
inline constexpr char kWaitingForReplicaPhase[] = "waiting for another replica's build";

// A graph's name in the cache: its mesh and its whole build record. A
// certified graph (max_error > 0) is a graph of its own: its params carry
// the first build's epsilon (CertifiedKeyEpsilon), which the bound
// decides, and the epsilon it is built with shows in its status once
// ready.
struct GraphKey {
  std::string mesh;
  DggParams params;
  double max_error = 0;  // 0: a plain graph
  friend auto operator<=>(const GraphKey&, const GraphKey&) = default;
};

// The epsilon of a certified graph's key (and of its first build, whose
// estimate admission uses).
double CertifiedKeyEpsilon(double max_error);

// The bounds a certified graph may be asked for, by a request or a config
// file: [1e-5, 0.5] (NaN is outside).
inline constexpr double kMinMaxError = 1e-5, kMaxMaxError = 0.5;
inline constexpr char kMaxErrorRange[] = "[1e-5, 0.5]";  // for messages
inline bool IsCertifiableBound(double max_error) {
  return max_error >= kMinMaxError && max_error <= kMaxMaxError;
}

struct GraphStatus {
  std::string mesh;
  // A certified graph's: its key's until it is ready, then the ones it was
  // built with.
  DggParams params;
  double epsilon = 0;    // params.epsilon, for callers that name graphs by it
  double max_error = 0;  // the key's: a certified graph's bound, or 0
  // A ready certified graph's certificate (built here or read back from
  // the sidecar beside its file).
  std::optional<GraphCertificate> certificate;
  GraphState state = GraphState::kQueued;
  std::string phase;
  double progress = 0;
  std::string error;
  uint64_t bytes = 0;  // the graph's arrays, resident or mapped
  // Resident memory for point-to-point bounds (core/query/landmarks.h), computed in
  // the background once the graph is ready, and for exact pairs' bounds
  // (core/query/exact_landmarks.h), once exact answers are asked of it.
  uint64_t landmark_bytes = 0;
  bool mapped = false;
  bool from_file = false;
  uint64_t nodes = 0;
  uint64_t edges = 0;
  double build_seconds = 0;
  // EstimateDggBuild for this mesh and build record, seconds on the
  // cache's build threads.
  uint64_t estimated_bytes = 0;
  double estimated_seconds = 0;
  int64_t last_used_unix_ms = 0;
  uint64_t version = 0;  // increases on every change
};

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_GRAPHS_GRAPH_KEY_H_
