// The gateway's answers as JSON: meshes, graphs and what a query says about
// its graph, in the contract's own spelling (docs/http.md: +inf as null,
// states as "READY", epsilon also as "eps"), not protobuf's JSON mapping,
// and a mesh's geometry written straight into one string. Apart from the handlers
// so that every route that returns a mesh or a graph writes it alike.
#ifndef GEODESIC_SERVER_GATEWAY_JSON_ANSWERS_H_
#define GEODESIC_SERVER_GATEWAY_JSON_ANSWERS_H_

#include <cstdint>
#include <string>

#include "absl/status/statusor.h"
#include "geodesic/v1/geodesic.pb.h"
#include "server/gateway/gateway_call.h"

namespace geodesic::server::gateway {

// +inf (unreachable) has no JSON form: null stands for it.
json JsonDistance(double d);

// What every query's answer says about the graph that gave it.
void AddEcho(const v1::QueryEcho& echo, json* out);

// A mesh and a graph as the list and get routes answer them.
json GraphJson(const v1::Graph& g);
json MeshJson(const v1::Mesh& m);

// What one number of an answer costs while it is made and sent as JSON: its
// value as it came (8 bytes), its node in the JSON tree (16, up to twice that
// as arrays grow) and its text (up to 24 characters and a comma).
constexpr uint64_t kJsonNumberBytes = 8 + 2 * 16 + 25;

// {"name", "fingerprint", "positions": [x, y, z, ...], "faces": [i, j, k,
// ...]} from GetGeometry's chunks: the mesh's arrays in file order, flat,
// written straight into one string of the size reserved for it (a tree of
// JSON values first would take several times the text).
class GeometryJson {
 public:
  // The longest text the chunks of the stream that `first` opens make: a
  // shortest round-trip double is at most 24 characters, a vertex id 10,
  // each with a comma.
  static uint64_t Bound(const v1::GeometryChunk& first);

  // Starts the text with `first`'s name and fingerprint; Add(first) next.
  GeometryJson(const v1::GeometryChunk& first, uint64_t bound);

  // INTERNAL when the chunk breaks the stream's order (every vertex before
  // any face) or passes the first chunk's totals.
  absl::Status Add(const v1::GeometryChunk& chunk);
  // The text; INTERNAL if the stream fell short of its totals.
  absl::StatusOr<std::string> Finish() &&;

 private:
  std::string text_;
  uint64_t vertex_values_, face_values_;  // still to come
  bool faces_begun_ = false;
  bool first_value_ = true;  // of the array being written
};

}  // namespace geodesic::server::gateway

#endif  // GEODESIC_SERVER_GATEWAY_JSON_ANSWERS_H_
