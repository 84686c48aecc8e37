// The RPCs of graphs: request, get, watch, cancel and list.
#include <algorithm>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <optional>
#include <string_view>
#include <thread>

#include "absl/cleanup/cleanup.h"
#include "absl/functional/function_ref.h"
#include "absl/status/status.h"
#include "absl/strings/cord.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/time/time.h"
#include "core/base/status.h"
#include "core/dgg/dgg_build.h"
#include "server/api/convert.h"
#include "server/base/echo.h"
#include "server/base/log.h"
#include "server/grpc/geodesic_service.h"
#include "server/grpc/rpc_support.h"
#include "server/limits/client_key.h"
#include "server/meshes/upload.h"

namespace geodesic::server {

grpc::Status GeodesicService::RequestGraph(grpc::ServerContext* ctx,
                                           const v1::RequestGraphRequest* req, v1::Graph* resp) {
  const v1::GraphSelector graph = SelectorOf(*req);
  return Handle("RequestGraph", ctx, graph.mesh(), [&](const Call& call) -> absl::Status {
    NameLocks::Hold hold(names_, graph.mesh(), absl::FromChrono(ctx->deadline()));
    if (!hold.held()) return NameBusy(graph.mesh());
    ASSIGN_OR_RETURN(const GraphKey key, Key(graph));
    auto m = FindMesh(key.mesh);
    if (!m.ok()) return m.status();
    ASSIGN_OR_RETURN(const GraphStatus started, StartGraph(key, *m, call.client));
    ToProto(started, resp);
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::GetGraph(grpc::ServerContext* ctx, const v1::GetGraphRequest* req,
                                       v1::Graph* resp) {
  const v1::GraphSelector graph = SelectorOf(*req);
  return Handle("GetGraph", ctx, graph.mesh(), [&](const Call& call) -> absl::Status {
    ASSIGN_OR_RETURN(const GraphKey key, Key(graph));
    auto g = graphs_->Get(key);
    if (!g.ok()) return g.status();
    ToProto(*g, resp);
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::WatchGraph(grpc::ServerContext* ctx, const v1::GetGraphRequest* req,
                                         grpc::ServerWriter<v1::Graph>* writer) {
  const v1::GraphSelector graph = SelectorOf(*req);
  return Handle("WatchGraph", ctx, graph.mesh(), [&](const Call& call) -> absl::Status {
    ASSIGN_OR_RETURN(const GraphKey key, Key(graph));
    StreamWatchdog::Watch watch = WatchStream("WatchGraph", ctx);
    auto g = graphs_->Get(key);
    while (g.ok()) {
      v1::Graph out;
      ToProto(*g, &out);
      RETURN_IF_ERROR(Send(watch, writer, out));
      if (g->state != GraphState::kQueued && g->state != GraphState::kBuilding &&
          g->state != GraphState::kLoading && g->state != GraphState::kPersisting) {
        return absl::OkStatus();
      }
      if (Cancelled(ctx)()) return absl::CancelledError("watch cancelled");
      g = graphs_->WaitForChange(key, g->version, absl::Now() + absl::Seconds(1));
    }
    return g.status();
  });
}

grpc::Status GeodesicService::CancelGraph(grpc::ServerContext* ctx,
                                          const v1::CancelGraphRequest* req, v1::Graph* resp) {
  const v1::GraphSelector graph = SelectorOf(*req);
  return Handle("CancelGraph", ctx, graph.mesh(), [&](const Call& call) -> absl::Status {
    NameLocks::Hold hold(names_, graph.mesh(), absl::FromChrono(ctx->deadline()));
    if (!hold.held()) return NameBusy(graph.mesh());
    ASSIGN_OR_RETURN(const GraphKey key, Key(graph));
    auto g = graphs_->Cancel(key);
    // A ready graph has no operation to cancel: it stays catalogued and
    // served. Anything else is forgotten, also when only another replica
    // requested it.
    const bool ready =
        g.ok() && (g->state == GraphState::kReady || g->state == GraphState::kEvicted);
    if (catalog_ && !ready) {
      RETURN_IF_ERROR(catalog_->ForgetGraph(key.mesh, key.params, key.max_error).status());
    }
    if (!g.ok()) return g.status();
    ToProto(*g, resp);
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::ListGraphs(grpc::ServerContext* ctx, const v1::ListGraphsRequest*,
                                         v1::ListGraphsResponse* resp) {
  return Handle("ListGraphs", ctx, "", [&](const Call& call) -> absl::Status {
    for (const auto& g : graphs_->List()) ToProto(g, resp->add_graphs());
    return absl::OkStatus();
  });
}

}  // namespace geodesic::server
