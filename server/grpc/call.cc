#include "server/grpc/call.h"

#include <cstdio>
#include <cstdlib>

namespace geodesic::server {
namespace {

constexpr RpcKind kRpcs[] = {
    // name              query  stream change
    {"RegisterMesh", false, false, true},   {"UploadMesh", false, true, false},
    {"RegisterRegion", false, false, true}, {"ListMeshes", false, false, false},
    {"GetMesh", false, false, false},       {"UnloadMesh", false, false, true},
    {"GetGeometry", false, true, false},    {"RequestGraph", false, false, true},
    {"GetGraph", false, false, false},      {"WatchGraph", false, true, false},
    {"CancelGraph", false, false, true},    {"ListGraphs", false, false, false},
    {"DistanceField", false, true, false},  {"Distance", true, false, false},
    {"Matrix", true, false, false},         {"MatrixRows", false, true, false},
    {"Snap", true, false, false},           {"SamplePoints", true, false, false},
};

}  // namespace

std::span<const RpcKind> Rpcs() { return kRpcs; }

const RpcKind& RpcNamed(std::string_view method) {
  for (const RpcKind& rpc : kRpcs) {
    if (method == rpc.name) return rpc;
  }
  std::fprintf(stderr, "geodesicd: RPC %.*s is missing from the table in server/grpc/call.cc\n",
               static_cast<int>(method.size()), method.data());
  std::abort();
}

}  // namespace geodesic::server
