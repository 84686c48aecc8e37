// The RPCs of meshes: registration by path, upload and region, listing,
// unloading and geometry.
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

grpc::Status GeodesicService::RegisterMesh(grpc::ServerContext* ctx,
                                           const v1::RegisterMeshRequest* req, v1::Mesh* resp) {
  return Handle("RegisterMesh", ctx, req->name(), [&](const Call& call) -> absl::Status {
    // Refused before the name is held: a name no mesh can have must not
    // wait for, or hold up, anything.
    RETURN_IF_ERROR(MeshRegistry::ValidateName(req->name()));
    NameLocks::Hold hold(names_, req->name(), absl::FromChrono(ctx->deadline()));
    if (!hold.held()) return NameBusy(req->name());
    const bool existed = meshes_->Get(req->name()).ok();
    auto m = meshes_->RegisterPath(req->name(), req->path(), req->repair_non_manifold());
    if (!m.ok()) return m.status();
    RETURN_IF_ERROR(Record(**m, existed));
    FillMesh(**m, resp);
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::UploadMesh(grpc::ServerContext* ctx,
                                         grpc::ServerReader<v1::UploadMeshRequest>* reader,
                                         v1::Mesh* resp) {
  std::string name;
  return Handle("UploadMesh", ctx, name, [&](const Call& call) -> absl::Status {
    UploadAssembler upload(limits_.max_upload_bytes);
    v1::UploadMeshRequest chunk;
    StreamWatchdog::Watch watch = WatchStream("UploadMesh", ctx);
    // A message that cannot be parsed ends the reads as the stream's end
    // does: the declared size tells the two apart.
    // The payload's bytes are counted against --memory-limit as they come,
    // until the mesh is registered (or refused): an upload declaring much
    // and sending little (one byte every few seconds, inside --idle-seconds)
    // holds only what it sent, and one that sends too slowly is closed.
    std::vector<std::shared_ptr<void>> payload;
    uint64_t counted = 0;
    const absl::Time started = absl::Now();
    while (Receive(watch, reader, &chunk)) {
      RETURN_IF_ERROR(upload.Add(chunk));
      name = upload.name();
      RETURN_IF_ERROR(CheckUploadRate(upload, absl::Now() - started));
      if (ledger_ != nullptr && upload.received_bytes() > counted) {
        ASSIGN_OR_RETURN(payload.emplace_back(),
                         ledger_->Reserve(upload.received_bytes() - counted,
                                          absl::StrFormat("the upload of '%s'", name)));
        counted = upload.received_bytes();
      }
    }
    // A cancelled stream ends the reads too: nothing of it is registered,
    // however much of it came.
    if (watch.closed()) return watch.Ended();
    if (ctx->IsCancelled()) {
      return absl::CancelledError("the upload was cancelled; nothing was registered");
    }
    RETURN_IF_ERROR(upload.Finish());
    NameLocks::Hold hold(names_, name, absl::FromChrono(ctx->deadline()));
    if (!hold.held()) return NameBusy(name);
    const bool existed = meshes_->Get(name).ok();
    auto m = upload.arrays()
                 ? meshes_->RegisterArrays(name, upload.vertices(), upload.faces(), upload.repair())
                 : meshes_->RegisterBytes(name, upload.format(), upload.bytes(), upload.repair());
    if (!m.ok()) return m.status();
    RETURN_IF_ERROR(Record(**m, existed));
    FillMesh(**m, resp);
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::RegisterRegion(grpc::ServerContext* ctx,
                                             const v1::RegisterRegionRequest* req, v1::Mesh* resp) {
  return Handle("RegisterRegion", ctx, req->name(), [&](const Call& call) -> absl::Status {
    RETURN_IF_ERROR(MeshRegistry::ValidateName(req->name()));
    if (req->vertex_ids().empty() == req->face_ids().empty()) {
      return absl::InvalidArgumentError(
          "a region is given by vertex_ids or by face_ids: exactly one of the two");
    }
    // The region's name and its parent's, in one order for every caller (no
    // two calls wait on each other): an unload of the parent cannot slip in
    // between the parent being found and the region being registered, which
    // left a region whose parent was gone.
    const absl::Time deadline = absl::FromChrono(ctx->deadline());
    const std::string& first = std::min(req->name(), req->parent());
    const std::string& second = std::max(req->name(), req->parent());
    NameLocks::Hold hold(names_, first, deadline);
    if (!hold.held()) return NameBusy(first);
    std::optional<NameLocks::Hold> hold_second;
    if (second != first) {
      hold_second.emplace(names_, second, deadline);
      if (!hold_second->held()) return NameBusy(second);
    }
    // The parent may have been registered on another replica.
    RETURN_IF_ERROR(FindMesh(req->parent()).status());
    const bool existed = meshes_->Get(req->name()).ok();
    const bool by_faces = !req->face_ids().empty();
    const auto& ids = by_faces ? req->face_ids() : req->vertex_ids();
    auto m = meshes_->RegisterRegion(req->name(), req->parent(),
                                     by_faces ? RegionMask::kFaces : RegionMask::kVertices,
                                     absl::MakeConstSpan(ids.data(), ids.size()));
    if (!m.ok()) return m.status();
    RETURN_IF_ERROR(Record(**m, existed));
    FillMesh(**m, resp);
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::ListMeshes(grpc::ServerContext* ctx, const v1::ListMeshesRequest*,
                                         v1::ListMeshesResponse* resp) {
  return Handle("ListMeshes", ctx, "", [&](const Call& call) -> absl::Status {
    for (const auto& m : meshes_->List()) FillMesh(*m, resp->add_meshes());
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::GetMesh(grpc::ServerContext* ctx, const v1::GetMeshRequest* req,
                                      v1::Mesh* resp) {
  return Handle("GetMesh", ctx, req->name(), [&](const Call& call) -> absl::Status {
    auto m = FindMesh(req->name());
    if (!m.ok()) return m.status();
    FillMesh(**m, resp);
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::UnloadMesh(grpc::ServerContext* ctx, const v1::UnloadMeshRequest* req,
                                         v1::UnloadMeshResponse*) {
  return Handle("UnloadMesh", ctx, req->name(), [&](const Call& call) -> absl::Status {
    NameLocks::Hold hold(names_, req->name(), absl::FromChrono(ctx->deadline()));
    if (!hold.held()) return NameBusy(req->name());
    // A region is cut again from its parent at every restart.
    for (const auto& m : meshes_->List()) {
      if (m->parent == req->name()) {
        return absl::FailedPreconditionError(
            absl::StrFormat("mesh '%s' has the region '%s' registered: unload the region first",
                            req->name(), m->name));
      }
    }
    // The catalog first: once it no longer lists the mesh, no restart or
    // replica brings it back.
    bool catalogued = false;
    if (catalog_) {
      ASSIGN_OR_RETURN(catalogued, catalog_->ForgetMesh(req->name()));
    }
    absl::Status s = meshes_->Remove(req->name());
    graphs_->DropMesh(req->name());
    return catalogued ? absl::OkStatus() : s;
  });
}

grpc::Status GeodesicService::GetGeometry(grpc::ServerContext* ctx, const v1::GetMeshRequest* req,
                                          grpc::ServerWriter<v1::GeometryChunk>* writer) {
  return Handle("GetGeometry", ctx, req->name(), [&](const Call& call) -> absl::Status {
    ASSIGN_OR_RETURN(std::shared_ptr<const RegisteredMesh> m, FindMesh(req->name()));
    const Mesh& mesh = *m->mesh;
    // Small chunks, whatever the mesh's size: a stream whose client does not
    // read holds one, and its serialized copy, until it is closed.
    constexpr int kValuesPerChunk = 1 << 16;
    v1::GeometryChunk chunk;
    chunk.set_name(m->name);
    chunk.set_fingerprint(absl::StrFormat("%016x", m->fingerprint));
    chunk.set_total_vertices(mesh.num_vertices());
    chunk.set_total_faces(mesh.corners().size() / 3);
    StreamWatchdog::Watch watch = WatchStream("GetGeometry", ctx);
    auto flush = [&](bool last) -> absl::Status {
      const int values = chunk.vertices_size() + chunk.faces_size();
      if (last ? chunk.ByteSizeLong() == 0 : values < kValuesPerChunk) return absl::OkStatus();
      RETURN_IF_ERROR(Send(watch, writer, chunk));
      chunk.Clear();
      return absl::OkStatus();
    };
    for (const Vec3& p : mesh.positions()) {
      chunk.add_vertices(p.x);
      chunk.add_vertices(p.y);
      chunk.add_vertices(p.z);
      RETURN_IF_ERROR(flush(false));
    }
    for (VertexId v : mesh.corners()) {
      chunk.add_faces(v);
      RETURN_IF_ERROR(flush(false));
    }
    return flush(true);
  });
}

}  // namespace geodesic::server
