// Every per-call limit of the gRPC service in one struct (geodesicd serve's
// flags fill it: server/app/serve_options.cc), and the request sizes those
// limits allow on the wire, which bound what gRPC and the handlers read.
#ifndef GEODESIC_SERVER_LIMITS_SERVICE_LIMITS_H_
#define GEODESIC_SERVER_LIMITS_SERVICE_LIMITS_H_

#include <cstdint>

namespace geodesic::server {

struct ServiceLimits {
  double default_epsilon = 1e-3;
  int max_inflight = 64;  // queries admitted, waiting or running; beyond: RESOURCE_EXHAUSTED
  int query_threads = 0;  // admitted queries running at once (0: the cores)
  // Server streams open (GetGeometry, MatrixRows, DistanceField, WatchGraph,
  // UploadMesh); beyond: RESOURCE_EXHAUSTED.
  int max_streams = 64;
  // A stream waiting on its client this long (a message unread, or not
  // sent) is closed (0: never).
  double idle_seconds = 60;
  // The largest message either way: an answer that cannot fit is refused
  // before it is computed.
  uint64_t max_message_bytes = uint64_t{64} << 20;
  int max_pairs = 10000;  // pairs per Distance call
  // Exact pairs per Distance call: each costs a window propagation, far
  // more than a graph pair.
  int max_exact_pairs = 256;
  int max_samples = 1024;  // SamplePoints count: each point costs a field
  // Queries one client may have admitted at once (0: half of max_inflight).
  int max_inflight_per_client = 0;
  // Streams one client may have open at once (0: half of max_streams).
  int max_streams_per_client = 0;
  // The windows one exact pair or matrix row may hold (a propagation keeps
  // them for its trace): past it the call fails with RESOURCE_EXHAUSTED, and
  // admission reserves it for each lane of an exact call.
  uint64_t max_exact_bytes = uint64_t{256} << 20;
  int max_sources = 1024;  // sources per field, rows/cols per matrix
  uint64_t max_upload_bytes = uint64_t{256} << 20;
  int field_chunk = 65536;  // values per streamed chunk
  bool log_requests = true;
  // A query on a graph never requested starts it (at the daemon's default
  // epsilon unless the query names one) and waits for it, up to the call's
  // deadline and at most build_wait_seconds; off: FAILED_PRECONDITION, for
  // operators who build every graph ahead (--config, RequestGraph).
  bool build_on_query = true;
  double build_wait_seconds = 300;
  // Build budget: graphs queued or being made at once, in all and started
  // by one client (RequestGraph or a query); past either, a new graph is
  // refused RESOURCE_EXHAUSTED. Joining a graph being made is always fine.
  int max_queued_builds = 8;
  int max_queued_builds_per_client = 2;
  // The smallest epsilon and certified bound a client may have built (their
  // cost grows steeply as they shrink); graphs the operator lists in
  // --config are not held to them.
  double min_epsilon = 1e-4;
  double min_max_error = 1e-3;
  // A query starts a graph never requested only at the default epsilon
  // (plain, no pseudo vertices), so that a query naming a new epsilon
  // cannot start a build; true: at any epsilon.
  bool auto_build_any_epsilon = false;
  // Graphs this daemon builds use exact fans (geodesicd serve --exact-fans):
  // part of the build record of every graph it requests.
  bool exact_fans = false;
};

// What a decoded request takes in memory per byte on the wire at most
// (measured: about 14 for pairs of vertex points), reserved before it is
// decoded.
inline constexpr uint64_t kDecodedBytesPerWireByte = 16;

// The largest valid request of each method the limits bound, on the wire.
uint64_t DistanceRequestBytes(const ServiceLimits& limits);
uint64_t MatrixRequestBytes(const ServiceLimits& limits);
uint64_t SnapRequestBytes(const ServiceLimits& limits);

// The largest request message a client may send under `limits`, so that
// gRPC refuses a larger one as it arrives: the lists --max-pairs and
// --max-sources allow on the wire, and at least room for the lists that
// grow with a mesh (a region's ids, a field's targets) and an upload's
// messages (kUploadMessageBytes each, upload.h).
uint64_t MaxRequestBytes(const ServiceLimits& limits);

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_LIMITS_SERVICE_LIMITS_H_
