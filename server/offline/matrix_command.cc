// geodesicd matrix: a sources x targets distance matrix on a DGG, streamed
// to a dense .npy or, within a radius, a sparse .npz.
#include <sys/resource.h>
#include <tbb/info.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <optional>

#include "CLI/CLI.hpp"
#include "absl/strings/str_format.h"
#include "core/base/status.h"
#include "core/base/thread_arena.h"
#include "core/dgg/graph_file.h"
#include "core/query/geodesic_engine.h"
#include "core/query/matrix_files.h"
#include "core/query/result_files.h"
#include "server/offline/commands.h"
#include "server/offline/common.h"

namespace geodesic::offline {
namespace {

struct MatrixFlags {
  std::string mesh_path, graph_path, out_path, dtype;
  std::vector<std::string> sources, targets;
  std::optional<double> radius;
  int threads = 0;
  bool json = false, repair = false;
  RegionFlags region;
};

// A radius for the sparse output: finite, above zero.
const CLI::Validator kFiniteRadius(
    [](std::string& text) -> std::string {
      try {
        const double v = std::stod(text);
        if (v > 0 && std::isfinite(v)) return "";
      } catch (const std::exception&) {
      }
      return "must be a finite distance above 0, got '" + text + "'";
    },
    "DISTANCE > 0");

void AddMatrixFlags(CLI::App& app, MatrixFlags& f) {
  constexpr char kPoints[] =
      "all (every mesh vertex, in file order; with a region, its vertices, or with --parent-ids "
      "every parent vertex, rows and columns outside the region +inf), point specs (v:ID, "
      "e:EDGE:T, f:FACE:B0,B1,B2, "
      "xyz:X,Y,Z) or @FILE (one spec per line, # comments)";
  app.add_option("--mesh", f.mesh_path,
                 "mesh file the graph was built for (with a region: its parent)")
      ->required();
  app.add_option("--graph", f.graph_path, "graph file (geodesicd build)")->required();
  app.add_option("--sources", f.sources, std::string("the rows: ") + kPoints)->required();
  app.add_option("--targets", f.targets, std::string("the columns: ") + kPoints)->required();
  app.add_option("--dtype", f.dtype, "entry type (float32: the float64 distance rounded)")
      ->required()
      ->check(CLI::IsMember({"float32", "float64"}));
  app.add_option("--out", f.out_path,
                 "the matrix: .npy (dense, +inf where unreachable) or, with --radius, .npz "
                 "(scipy.sparse CSR, scipy.sparse.load_npz reads it)")
      ->required();
  app.add_option("--radius", f.radius,
                 "keep only the entries within this distance (the diagonal's zeros included), "
                 "as a sparse .npz")
      ->check(kFiniteRadius);
  app.add_option("--threads", f.threads, "threads, each computing whole rows (0: all cores)")
      ->check(CLI::NonNegativeNumber);
  app.add_flag("--json", f.json, "print a JSON object");
  AddRepairFlag(app, &f.repair);
  AddRegionFlags(app, &f.region, true);
}

// A bad output name or a missing directory is refused before any work.
absl::Status CheckOutput(const MatrixFlags& f) {
  const bool sparse = f.radius.has_value();
  if (absl::Status s = CheckMatrixPath(f.out_path, sparse); !s.ok()) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s (%s)", s.message(),
                        sparse ? "--radius writes a sparse .npz"
                               : "a dense matrix is a .npy; .npz needs --radius"));
  }
  const std::filesystem::path parent = std::filesystem::path(f.out_path).parent_path();
  const std::filesystem::path dir = parent.empty() ? "." : parent;
  std::error_code ec;
  if (!std::filesystem::is_directory(dir, ec)) {
    return absl::NotFoundError(
        absl::StrFormat("cannot write %s: %s is not a directory", f.out_path, dir.string()));
  }
  return absl::OkStatus();
}

struct SparseRow {
  std::vector<int32_t> columns;
  std::vector<double> values;
};

// Where the computed matrix goes in the one written: they differ only with
// --parent-ids, where `all` lists parent vertices outside the region, whose
// rows and columns are +inf (absent from a sparse matrix), never computed.
struct Layout {
  size_t rows = 0, columns = 0;
  std::vector<size_t> row_of;         // per computed row, its row in the file
  std::vector<uint32_t> column_slot;  // per file column, its computed column or kNone
  std::vector<size_t> file_column;    // per computed column, its file column
  bool identity = true;

  Layout(const WorkPoints& sources, const WorkPoints& targets)
      : rows(sources.slot.size()), columns(targets.slot.size()), column_slot(targets.slot) {
    for (size_t i = 0; i < sources.slot.size(); ++i) {
      if (sources.slot[i] != kNone) row_of.push_back(i);
    }
    identity =
        row_of.size() == rows && sources.points.size() == rows && targets.points.size() == columns;
    file_column.resize(targets.points.size());
    for (size_t j = 0; j < columns; ++j) {
      if (column_slot[j] != kNone) file_column[column_slot[j]] = j;
    }
  }
  // A computed row as the file's; `row` itself when they are the same.
  template <typename T>
  absl::Span<const T> Expand(absl::Span<const T> row, std::vector<T>& out) const {
    if (identity) return row;
    out.assign(columns, static_cast<T>(kInfinity));
    for (size_t j = 0; j < columns; ++j) {
      if (column_slot[j] != kNone) out[j] = row[column_slot[j]];
    }
    return out;
  }
  // A computed row's entries (columns ascending) in the file's columns,
  // ascending too.
  SparseRow InFileColumns(absl::Span<const uint32_t> columns,
                          absl::Span<const double> values) const {
    SparseRow row;
    if (identity) {
      row.columns.assign(columns.begin(), columns.end());
      row.values.assign(values.begin(), values.end());
      return row;
    }
    std::vector<std::pair<size_t, double>> entries;
    for (size_t e = 0; e < columns.size(); ++e) {
      entries.emplace_back(file_column[columns[e]], values[e]);
    }
    std::sort(entries.begin(), entries.end());
    for (const auto& [j, d] : entries) {
      row.columns.push_back(static_cast<int32_t>(j));
      row.values.push_back(d);
    }
    return row;
  }
};

struct Written {
  uint64_t bytes = 0;
  uint64_t nonzeros = 0;  // sparse only
};

// Each row goes to its place in the file from the thread that computed it.
absl::StatusOr<Written> WriteDense(const GeodesicEngine& engine,
                                   absl::Span<const SurfacePoint> sources,
                                   absl::Span<const SurfacePoint> targets, const Layout& layout,
                                   const std::string& path, MatrixDtype dtype) {
  ASSIGN_OR_RETURN(DenseMatrixFile file,
                   DenseMatrixFile::Create(path, layout.rows, layout.columns, dtype));
  auto write = [&]<typename T>(size_t i, absl::Span<const T> row) {
    std::vector<T> expanded;
    return file.WriteRow(layout.row_of[i], layout.Expand(row, expanded));
  };
  MatrixRowSink sink;
  if (dtype == MatrixDtype::kFloat32) {
    sink.float32_row = [&](size_t i, absl::Span<const float> row) { return write(i, row); };
  } else {
    sink.row = [&](size_t i, absl::Span<const double> row) { return write(i, row); };
  }
  // One matrix is all this process makes: the copy of the edges whose fans
  // narrow is held only while it is made.
  MatrixOptions options;
  options.narrow_fans = true;
  RETURN_IF_ERROR(engine.StreamMatrix(sources, targets, options, sink));
  if (layout.row_of.size() < layout.rows) {
    const std::vector<double> outside(layout.columns, kInfinity);
    std::vector<bool> computed(layout.rows, false);
    for (size_t r : layout.row_of) computed[r] = true;
    for (size_t r = 0; r < layout.rows; ++r) {
      if (!computed[r]) RETURN_IF_ERROR(file.WriteRow(r, outside));
    }
  }
  ASSIGN_OR_RETURN(const uint64_t bytes, std::move(file).Commit());
  return Written{bytes, 0};
}

// The .npz's rows must be appended in order, so rows are computed in
// batches: each batch's rows, kept within the radius, wait in memory until
// the batch is done, then go to the file in order.
absl::StatusOr<Written> WriteSparse(const GeodesicEngine& engine,
                                    absl::Span<const SurfacePoint> sources,
                                    absl::Span<const SurfacePoint> targets, const Layout& layout,
                                    const std::string& path, MatrixDtype dtype, double radius,
                                    size_t batch_rows) {
  ASSIGN_OR_RETURN(SparseMatrixFile file,
                   SparseMatrixFile::Create(path, layout.rows, layout.columns, dtype));
  std::vector<SparseRow> batch(batch_rows);
  size_t appended = 0, file_rows = 0;
  // Rows outside the region have no entry within any radius.
  auto empty_rows_until = [&](size_t end) -> absl::Status {
    for (; file_rows < end; ++file_rows) RETURN_IF_ERROR(file.AppendRow({}, {}));
    return absl::OkStatus();
  };
  MatrixRowSink sink;
  sink.batch_rows = batch_rows;
  sink.sparse_row = [&](size_t i, absl::Span<const uint32_t> columns,
                        absl::Span<const double> values) {
    batch[i % batch_rows] = layout.InFileColumns(columns, values);
    return absl::OkStatus();
  };
  sink.batch_done = [&](size_t end) -> absl::Status {
    for (; appended < end; ++appended) {
      RETURN_IF_ERROR(empty_rows_until(layout.row_of[appended]));
      SparseRow& row = batch[appended % batch_rows];
      RETURN_IF_ERROR(file.AppendRow(row.columns, row.values));
      row = SparseRow();
      ++file_rows;
    }
    return absl::OkStatus();
  };
  // The search stops at the radius: a neighbourhood costs what it holds.
  MatrixOptions options;
  options.max_distance = radius;
  RETURN_IF_ERROR(engine.StreamMatrix(sources, targets, options, sink));
  RETURN_IF_ERROR(empty_rows_until(layout.rows));
  const uint64_t nonzeros = file.nonzeros();
  ASSIGN_OR_RETURN(const uint64_t bytes, std::move(file).Commit());
  return Written{bytes, nonzeros};
}

uint64_t PeakRssBytes() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return uint64_t(usage.ru_maxrss) * 1024;  // Linux reports kilobytes
}

// The matrix of the flags' points, written in the arena of --threads.
absl::StatusOr<Written> ComputeAndWrite(const MatrixFlags& f, const GeodesicEngine& engine,
                                        const WorkPoints& sources, const WorkPoints& targets) {
  const Layout layout(sources, targets);
  const MatrixDtype dtype = f.dtype == "float32" ? MatrixDtype::kFloat32 : MatrixDtype::kFloat64;
  const int threads = f.threads > 0 ? f.threads : tbb::info::default_concurrency();
  // A few rows per thread per batch: rows take about as long as each
  // other, so a batch's last rows leave threads idle for about a row's
  // time, a small share of a batch.
  const size_t batch_rows = 8 * size_t(threads);
  absl::StatusOr<Written> written;
  ThreadArena(threads).execute([&] {
    written = f.radius
                  ? WriteSparse(engine, sources.points, targets.points, layout, f.out_path, dtype,
                                *f.radius, batch_rows)
                  : WriteDense(engine, sources.points, targets.points, layout, f.out_path, dtype);
  });
  return written;
}

void Report(const MatrixFlags& f, const WorkMesh& work, size_t rows, size_t columns,
            const Written& written, double seconds) {
  if (!f.json) {
    const std::string kept =
        f.radius ? absl::StrFormat(", %u entries within %g", written.nonzeros, *f.radius) : "";
    std::printf("%s", absl::StrFormat("matrix %u x %u %s%s to %s: %u bytes in %.3f s\n", rows,
                                      columns, f.dtype, kept, f.out_path, written.bytes, seconds)
                          .c_str());
    return;
  }
  Json out = {{"rows", rows},       {"columns", columns},     {"dtype", f.dtype},
              {"seconds", seconds}, {"bytes", written.bytes}, {"peak_rss_bytes", PeakRssBytes()}};
  if (f.radius) {
    out["radius"] = *f.radius;
    out["nonzeros"] = written.nonzeros;
  }
  work.AddJson(out);
  PrintJson(out);
}

}  // namespace

int RunMatrix(int argc, char** argv) {
  CLI::App app{"Distance matrix between two point lists on a discrete geodesic graph",
               "geodesicd matrix"};
  app.option_defaults()->always_capture_default();  // --help shows defaults
  MatrixFlags f;
  AddMatrixFlags(app, f);
  CLI11_PARSE(app, argc, argv);
  if (absl::Status s = CheckOutput(f); !s.ok()) return Fail("matrix", s);
  auto work = LoadWorkMesh(f.mesh_path, f.repair, f.region);
  if (!work.ok()) return Fail("matrix", work.status());
  auto graph = GraphFile::Open(f.graph_path, *work->mesh(), GraphFile::Check::kFull);
  if (!graph.ok()) return Fail("matrix", graph.status());
  PointResolver resolver(f.region.parent_ids ? *work->parent : *work->mesh());
  auto sources = ResolveWorkPoints(*work, f.region.parent_ids, resolver, f.sources, "--sources");
  if (!sources.ok()) return Fail("matrix", sources.status());
  auto targets = ResolveWorkPoints(*work, f.region.parent_ids, resolver, f.targets, "--targets");
  if (!targets.ok()) return Fail("matrix", targets.status());
  GeodesicEngine engine(work->mesh(), *graph);
  const auto t0 = std::chrono::steady_clock::now();
  auto written = ComputeAndWrite(f, engine, *sources, *targets);
  if (!written.ok()) return Fail("matrix", written.status());
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  Report(f, *work, sources->slot.size(), targets->slot.size(), *written, seconds);
  return 0;
}

}  // namespace geodesic::offline
