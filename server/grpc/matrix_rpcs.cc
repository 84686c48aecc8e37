// The matrix RPCs: Matrix answers in one message, MatrixRows streams row
// blocks, dense or sparse within a radius.
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
namespace {

// Packed matrices are the host's own bytes, which the wire format promises
// to be little-endian.
static_assert(std::endian::native == std::endian::little,
              "packed matrix values are copied as the host holds them");

// Bytes of one value of a packed dtype; 0 for MATRIX_DTYPE_DEFAULT, whose
// values travel as repeated doubles.
size_t PackedBytes(v1::MatrixDtype dtype) {
  switch (dtype) {
    case v1::MATRIX_DTYPE_FLOAT32:
      return sizeof(float);
    case v1::MATRIX_DTYPE_FLOAT64:
      return sizeof(double);
    default:
      return 0;
  }
}

// A sparse row's entries within the radius, as the chunk's bytes will
// hold them; +inf (unreachable) is never within a finite radius.
struct SparseRow {
  std::string indices, values;
  uint64_t count = 0;
};

// A row's entries within `radius` (exact rows come with every finite entry:
// their search has no limit).
SparseRow WithinRadius(absl::Span<const uint32_t> columns, absl::Span<const double> values,
                       double radius, bool narrow) {
  SparseRow kept;
  for (size_t e = 0; e < columns.size(); ++e) {
    if (!(values[e] <= radius)) continue;
    kept.indices.append(reinterpret_cast<const char*>(&columns[e]), sizeof(uint32_t));
    if (narrow) {
      const float value = static_cast<float>(values[e]);
      kept.values.append(reinterpret_cast<const char*>(&value), sizeof value);
    } else {
      kept.values.append(reinterpret_cast<const char*>(&values[e]), sizeof(double));
    }
    ++kept.count;
  }
  return kept;
}

// The first chunk->rows() staged rows as the chunk's CSR bytes (indptr,
// indices, values), each staged row emptied for the next block.
void MoveSparseRows(std::vector<SparseRow>& staged, v1::MatrixRowsChunk* chunk) {
  std::string* indptr = chunk->mutable_indptr();
  uint64_t offset = 0;
  indptr->append(reinterpret_cast<const char*>(&offset), sizeof offset);
  for (size_t k = 0; k < chunk->rows(); ++k) {
    SparseRow& row = staged[k];
    offset += row.count;
    indptr->append(reinterpret_cast<const char*>(&offset), sizeof offset);
    chunk->mutable_indices()->append(row.indices);
    chunk->mutable_values()->append(row.values);
    row = SparseRow();
  }
}

// Where the rows of a dense matrix go as they are computed: row i to
// `dense` (the reply's values, or the block's, as the block being filled
// sets it) at row i % block_rows, float32 rows as they come, rounded
// already (most straight from the sweep), float64 ones copied.
MatrixRowSink DenseSink(size_t block_rows, bool narrow, char* const& dense) {
  MatrixRowSink sink;
  if (narrow) {
    sink.float32_row = [=, &dense](size_t i, absl::Span<const float> row) {
      std::memcpy(dense + (i % block_rows) * row.size() * sizeof(float), row.data(),
                  row.size() * sizeof(float));
      return absl::OkStatus();
    };
  } else {
    sink.row = [=, &dense](size_t i, absl::Span<const double> row) {
      std::memcpy(dense + (i % block_rows) * row.size() * sizeof(double), row.data(),
                  row.size() * sizeof(double));
      return absl::OkStatus();
    };
  }
  return sink;
}

// Where a MatrixRows block's rows go as they are computed, in a block of
// `block_rows`: with a `radius` (> 0), the entries within it staged; else
// as DenseSink puts them.
MatrixRowSink BlockSink(size_t block_rows, double radius, bool narrow, char* const& dense,
                        std::vector<SparseRow>& staged) {
  MatrixRowSink sink;
  if (radius > 0) {
    sink.sparse_row = [=, &staged](size_t i, absl::Span<const uint32_t> columns,
                                   absl::Span<const double> values) {
      staged[i % block_rows] = WithinRadius(columns, values, radius, narrow);
      return absl::OkStatus();
    };
  } else {
    sink = DenseSink(block_rows, narrow, dense);
  }
  sink.batch_rows = block_rows;
  return sink;
}

}  // namespace

absl::Status GeodesicService::CheckMatrixLimits(const v1::MatrixRequest& req, bool streamed) {
  if (!std::isfinite(req.radius()) || req.radius() < 0) {
    return absl::InvalidArgumentError(
        absl::StrFormat("radius %g is not a finite distance >= 0 (0: dense rows)", req.radius()));
  }
  if (!v1::MatrixDtype_IsValid(req.dtype())) {
    return absl::InvalidArgumentError(
        absl::StrFormat("dtype %d is not a MatrixDtype", req.dtype()));
  }
  if (req.all_sources() && req.sources_size() > 0) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "all_sources and %d explicit sources: give one or the other", req.sources_size()));
  }
  if (req.all_targets() && req.targets_size() > 0) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "all_targets and %d explicit targets: give one or the other", req.targets_size()));
  }
  if (!streamed && req.radius() > 0) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "radius %g asks for sparse rows, which only MatrixRows answers", req.radius()));
  }
  uint64_t rows = req.sources_size(), cols = req.targets_size();
  if (!streamed && (req.all_sources() || req.all_targets())) {
    // Counted before any graph is waited for or built, so that a refusal
    // costs nothing.
    ASSIGN_OR_RETURN(std::shared_ptr<const RegisteredMesh> mesh, FindMesh(SelectorOf(req).mesh()));
    if (req.all_sources()) rows = mesh->mesh->num_vertices();
    if (req.all_targets()) cols = mesh->mesh->num_vertices();
  }
  if (rows <= uint64_t(limits_.max_sources) && cols <= uint64_t(limits_.max_pairs)) {
    return absl::OkStatus();
  }
  return OverLimits(
      absl::StrFormat("matrix of %u x %u exceeds the limits (%d sources, %d targets)%s", rows, cols,
                      limits_.max_sources, limits_.max_pairs,
                      req.all_sources() || req.all_targets()
                          ? "; MatrixRows streams all_sources and all_targets of any mesh"
                          : ""),
      {{"max-sources", limits_.max_sources}, {"max-pairs", limits_.max_pairs}});
}

absl::StatusOr<GeodesicService::MatrixQuery> GeodesicService::PrepareMatrix(
    const v1::MatrixRequest& req, const Call& call) {
  MatrixQuery q;
  ASSIGN_OR_RETURN(q.key, Key(SelectorOf(req)));
  ASSIGN_OR_RETURN(q.engine, AcquireEngine(q.key, call));
  if (req.exact()) graphs_->WantExactLandmarks(q.key);
  const Mesh& mesh = q.engine->mesh();
  ASSIGN_OR_RETURN(q.sources, PointsFromProto(req.sources(), mesh, "source"));
  ASSIGN_OR_RETURN(q.targets, PointsFromProto(req.targets(), mesh, "target"));
  if (req.all_sources()) q.sources = AllVertices(mesh);
  if (req.all_targets()) q.targets = AllVertices(mesh);
  return q;
}

uint64_t GeodesicService::MatrixScratchBytes(const MatrixQuery& q,
                                             const v1::MatrixRequest& req) const {
  const uint64_t lanes =
      std::clamp<uint64_t>(q.sources.size(), 1, std::thread::hardware_concurrency());
  return FieldScratchBytes(*q.engine) + q.targets.size() * sizeof(double) +
         (req.exact() ? lanes * limits_.max_exact_bytes : 0);
}

MatrixOptions GeodesicService::MatrixOptionsOf(const v1::MatrixRequest& req,
                                               grpc::ServerContext* ctx) const {
  MatrixOptions options;
  options.cancelled = Cancelled(ctx);
  options.exact = req.exact();
  options.exact_max_bytes = limits_.max_exact_bytes;
  // Sparse rows: the search stops at the radius. Not for exact rows, whose
  // graph entries just past it may still be exact ones within it.
  if (req.radius() > 0 && !req.exact()) options.max_distance = req.radius();
  return options;
}

grpc::Status GeodesicService::Matrix(grpc::ServerContext* ctx, const v1::MatrixRequest* req,
                                     v1::MatrixResponse* resp) {
  const v1::GraphSelector graph = SelectorOf(*req);
  return Handle("Matrix", ctx, graph.mesh(), [&](const Call& call) -> absl::Status {
    RETURN_IF_ERROR(CheckMatrixLimits(*req, /*streamed=*/false));
    const size_t value_bytes = PackedBytes(req->dtype());
    auto answer_of = [&](uint64_t rows, uint64_t cols) {
      return rows * cols * (value_bytes > 0 ? value_bytes : 9) + kAnswerOverhead;
    };
    if (!req->all_sources() && !req->all_targets()) {
      // Sized before the graph is waited for: a refusal costs nothing.
      RETURN_IF_ERROR(CheckAnswerSize(
          absl::StrFormat("a %d x %d matrix", req->sources_size(), req->targets_size()),
          answer_of(req->sources_size(), req->targets_size())));
    }
    ASSIGN_OR_RETURN(MatrixQuery q, PrepareMatrix(*req, call));
    const GraphKey& key = q.key;
    const std::vector<SurfacePoint>& sources = q.sources;
    const std::vector<SurfacePoint>& targets = q.targets;
    const uint64_t answer = answer_of(sources.size(), targets.size());
    RETURN_IF_ERROR(CheckAnswerSize(
        absl::StrFormat("a %u x %u matrix", sources.size(), targets.size()), answer));
    // The solver's distances, then the reply beside them and, once the
    // handler returns, the reply's serialized copy.
    const uint64_t scratch = MatrixScratchBytes(q, *req);
    ASSIGN_OR_RETURN(Admission::Ticket run, StartQuery(call, 2 * answer, scratch));
    absl::Time slice_start = absl::Now();
    // One fan-restricted field per row (the "lc" solver), joined at the
    // targets as Distance joins its points; "exact" when rows are made exact.
    FillEcho(Built(key, *q.engine), req->exact() ? "exact" : "lc", resp->mutable_echo());
    resp->set_rows(sources.size());
    resp->set_cols(targets.size());
    // Rows go straight into the reply's values or bytes, each where it
    // belongs.
    char* base = nullptr;
    const bool narrow = req->dtype() == v1::MATRIX_DTYPE_FLOAT32;
    if (value_bytes == 0) {
      resp->mutable_distances()->Resize(static_cast<int>(sources.size() * targets.size()), 0.0);
      base = reinterpret_cast<char*>(resp->mutable_distances()->mutable_data());
    } else {
      resp->set_dtype(req->dtype());
      std::string* packed = resp->mutable_packed();
      packed->resize(sources.size() * targets.size() * value_bytes);
      base = packed->data();
    }
    MatrixRowSink sink = DenseSink(std::max<size_t>(1, sources.size()), narrow, base);
    if (req->exact()) {
      // Exact rows go a lane group per core at a time, each batch a slice
      // after which a waiting client's query may run.
      sink.batch_rows = size_t{kFieldLanes} * std::max(1u, std::thread::hardware_concurrency());
      sink.batch_done = [&](size_t) { return NextSlice(call, run, slice_start, scratch); };
    }
    RETURN_IF_ERROR(q.engine->StreamMatrix(sources, targets, MatrixOptionsOf(*req, ctx), sink));
    HoldUntilSent(ctx, std::move(run));
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::MatrixRows(grpc::ServerContext* ctx, const v1::MatrixRequest* req,
                                         grpc::ServerWriter<v1::MatrixRowsChunk>* writer) {
  const v1::GraphSelector graph = SelectorOf(*req);
  // A query, admitted in the body: the stream gives its place back once its
  // first block is computed.
  return Handle("MatrixRows", ctx, graph.mesh(), [&](const Call& call) -> absl::Status {
    ASSIGN_OR_RETURN(Admission::Ticket admitted, AdmitQuery(call));
    RETURN_IF_ERROR(CheckMatrixLimits(*req, /*streamed=*/true));
    ASSIGN_OR_RETURN(MatrixQuery q, PrepareMatrix(*req, call));
    const std::vector<SurfacePoint>& sources = q.sources;
    const std::vector<SurfacePoint>& targets = q.targets;
    const bool sparse = req->radius() > 0;
    const bool narrow = req->dtype() == v1::MATRIX_DTYPE_FLOAT32;
    const size_t value_bytes = PackedBytes(req->dtype());
    // What the values travel as: a sparse request without a dtype gets
    // float64 bytes, since it has no repeated form to fall back on.
    const v1::MatrixDtype dtype =
        sparse && value_bytes == 0 ? v1::MATRIX_DTYPE_FLOAT64 : req->dtype();
    // Wire bytes per entry, at most: a repeated double with its share of
    // tags, a packed value, or a sparse entry's column and value.
    const uint64_t entry_bytes = sparse            ? sizeof(uint32_t) + (narrow ? 4 : 8)
                                 : value_bytes > 0 ? value_bytes
                                                   : 9;
    // Blocks small enough that the server holds one at a time, large
    // enough that framing stays negligible.
    constexpr uint64_t kBlockBytes = uint64_t{4} << 20;
    const size_t cols = std::max<size_t>(1, targets.size());
    const size_t block_rows = std::max<size_t>(1, kBlockBytes / (entry_bytes * cols));
    const uint64_t block_answer =
        block_rows * (cols * entry_bytes + (sparse ? sizeof(uint64_t) : 0)) + kAnswerOverhead;
    RETURN_IF_ERROR(
        CheckAnswerSize(absl::StrFormat("a block of %u rows", block_rows), block_answer));
    // A block's rows as computed (sparse ones staged per row), then the
    // chunk's serialized copy. Held while a block is computed, not while it
    // is sent: a client that reads slowly, or not at all, keeps no slot.
    // Later blocks wait their turn without being admitted again, so that a
    // stream once started is not refused halfway (--max-streams bounds them).
    auto start_block = [&] {
      return StartQuery(call, 2 * block_answer, MatrixScratchBytes(q, *req));
    };
    ASSIGN_OR_RETURN(Admission::Ticket run, start_block());
    StreamWatchdog::Watch watch = WatchStream("MatrixRows", ctx);
    v1::MatrixRowsChunk chunk;
    char* dense = nullptr;  // the block's rows, written in place by the threads computing them
    std::vector<SparseRow> staged(sparse ? block_rows : 0);
    auto begin_block = [&](size_t first) {
      const size_t n = std::min(block_rows, sources.size() - first);
      chunk.Clear();
      if (first == 0) {
        FillEcho(Built(q.key, *q.engine), req->exact() ? "exact" : "lc", chunk.mutable_echo());
      }
      chunk.set_first_row(first);
      chunk.set_rows(n);
      chunk.set_cols(targets.size());
      chunk.set_total_rows(sources.size());
      chunk.set_dtype(dtype);
      if (sparse) return;
      if (value_bytes == 0) {
        chunk.mutable_distances()->Resize(static_cast<int>(n * targets.size()), 0.0);
        dense = reinterpret_cast<char*>(chunk.mutable_distances()->mutable_data());
      } else {
        std::string* packed = chunk.mutable_packed();
        packed->resize(n * targets.size() * value_bytes);
        dense = packed->data();
      }
    };
    MatrixRowSink sink = BlockSink(block_rows, sparse ? req->radius() : 0, narrow, dense, staged);
    sink.batch_done = [&](size_t end) -> absl::Status {
      if (sparse) MoveSparseRows(staged, &chunk);
      {
        // The block's bytes stay counted while the client takes them.
        const Admission::Ticket sending = admission_.KeepAnswer(std::move(run));
        admitted.Release();
        RETURN_IF_ERROR(Send(watch, writer, chunk));
      }
      if (end == sources.size()) return absl::OkStatus();
      begin_block(end);
      ASSIGN_OR_RETURN(run, start_block());
      return absl::OkStatus();
    };
    begin_block(0);
    if (sources.empty()) {
      // No batch runs: the one block says the matrix has no rows.
      run.Release();
      admitted.Release();
      return Send(watch, writer, chunk);
    }
    return q.engine->StreamMatrix(sources, targets, MatrixOptionsOf(*req, ctx), sink);
  });
}

}  // namespace geodesic::server
