// The gateway's answers as JSON: meshes, graphs and what a query says about
// its graph, in the contract's own spelling (docs/http.md: +inf as null,
// states as "READY", epsilon as "eps"), not protobuf's JSON mapping, and a
// mesh's geometry written straight into one string. Apart from the handlers
// so that every route that returns a mesh or a graph writes it alike.
#ifndef GEODESIC_SERVER_GATEWAY_JSON_ANSWERS_H_
#define GEODESIC_SERVER_GATEWAY_JSON_ANSWERS_H_

#include <cstdint>
#include <string>

#include "core/mesh/mesh.h"
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

// The longest text GeometryJson writes for `mesh`: a shortest round-trip
// double is at most 24 characters, a vertex id 10, each with a comma.
uint64_t GeometryJsonBound(const Mesh& mesh);

// {"name", "fingerprint", "positions": [x, y, z, ...], "faces": [i, j, k,
// ...]}: the registry's arrays in file order, flat.
std::string GeometryJson(const std::string& name, const json& fingerprint, const Mesh& mesh,
                         uint64_t bound);

}  // namespace geodesic::server::gateway

#endif  // GEODESIC_SERVER_GATEWAY_JSON_ANSWERS_H_
