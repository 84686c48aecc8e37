// The gRPC service on a real server on 127.0.0.1 (port 0, read back), in this
// process: handlers, status codes, the build record of graphs, and a field
// streamed in several chunks, against the core's own answers.
#include <grpcpp/grpcpp.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>
#include <numeric>
#include <set>
#include <thread>
#include <tuple>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/exact/exact_geodesic.h"
#include "core/mesh/mesh_io.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "server/api/convert.h"
#include "server/grpc/geodesic_service.h"

namespace geodesic::server {
namespace {

using ::testing::HasSubstr;

class ServiceTest : public ::testing::Test {
 protected:
  // Tests change limits_ between TearDown() and SetUp(), which keeps them.
  ServiceTest() {
    limits_.field_chunk = 1000;  // spot's 2,930 values stream in 3 chunks
    limits_.max_pairs = 50;
    limits_.log_requests = false;
  }
  void SetUp() override {
    registry_ = std::make_unique<MeshRegistry>(std::string(GEODESIC_SOURCE_DIR) + "/data");
    GraphCache::Options options;
    options.build_threads = 2;
    cache_ = std::make_unique<GraphCache>(options);
    service_ = std::make_unique<GeodesicService>(registry_.get(), cache_.get(), &metrics_, limits_);
    grpc::ServerBuilder builder;
    int port = 0;
    builder.AddListeningPort("127.0.0.1:0", grpc::InsecureServerCredentials(), &port);
    builder.RegisterService(service_.get());
    server_ = builder.BuildAndStart();
    ASSERT_NE(server_, nullptr);
    ASSERT_GT(port, 0);
    stub_ = v1::Geodesic::NewStub(
        grpc::CreateChannel(absl::StrCat("127.0.0.1:", port), grpc::InsecureChannelCredentials()));
  }
  void TearDown() override {
    server_->Shutdown();
    server_.reset();
  }
  // Registers spot and waits for its graph at `eps`.
  void ReadySpot(double eps, bool pseudo = false) {
    if (!registry_->Get("spot").ok()) {
      grpc::ClientContext ctx;
      v1::RegisterMeshRequest req;
      req.set_name("spot");
      req.set_path("spot.obj");
      v1::Mesh mesh;
      ASSERT_TRUE(stub_->RegisterMesh(&ctx, req, &mesh).ok());
      EXPECT_EQ(mesh.diagnostics().vertices(), 2930u);
    }
    {
      grpc::ClientContext ctx;
      v1::RequestGraphRequest req;
      req.set_mesh("spot");
      req.set_epsilon(eps);
      req.set_pseudo_vertices(pseudo);
      v1::Graph graph;
      ASSERT_TRUE(stub_->RequestGraph(&ctx, req, &graph).ok());
    }
    grpc::ClientContext ctx;
    v1::GetGraphRequest req;
    req.set_mesh("spot");
    req.set_epsilon(eps);
    req.set_pseudo_vertices(pseudo);
    auto watch = stub_->WatchGraph(&ctx, req);
    v1::Graph last;
    while (watch->Read(&last)) {
    }
    ASSERT_TRUE(watch->Finish().ok());
    ASSERT_EQ(last.state(), v1::GRAPH_STATE_READY) << last.error();
    EXPECT_EQ(last.pseudo_vertices(), pseudo);
    EXPECT_EQ(last.candidate_rule(), kCandidateRuleVersion);
  }
  std::shared_ptr<const GeodesicEngine> Engine(double eps, bool pseudo = false) {
    GraphKey key{"spot", DggParams{}};
    key.params.epsilon = eps;
    key.params.pseudo_vertices = pseudo;
    auto engine = cache_->Acquire(key);
    EXPECT_TRUE(engine.ok()) << engine.status();
    return engine.ok() ? *engine : nullptr;
  }

  ServiceLimits limits_;
  Metrics metrics_;
  std::unique_ptr<MeshRegistry> registry_;
  std::unique_ptr<GraphCache> cache_;
  std::unique_ptr<GeodesicService> service_;
  std::unique_ptr<grpc::Server> server_;
  std::unique_ptr<v1::Geodesic::Stub> stub_;
};

v1::SurfacePoint Vertex(uint32_t v) { return ToProto(SurfacePoint::Vertex(v)); }
v1::SurfacePoint Face(uint32_t f, double b0, double b1, double b2) {
  return ToProto(SurfacePoint::Face(f, b0, b1, b2));
}

TEST_F(ServiceTest, DiagnosticsAreTypedFieldsEqualToTheCoresReport) {
  grpc::ClientContext ctx;
  v1::RegisterMeshRequest req;
  req.set_name("spot");
  req.set_path("spot.obj");
  v1::Mesh mesh;
  ASSERT_TRUE(stub_->RegisterMesh(&ctx, req, &mesh).ok());
  const v1::MeshDiagnostics& d = mesh.diagnostics();
  MeshDiagnostics local;
  ASSERT_TRUE(LoadMesh(std::string(GEODESIC_SOURCE_DIR) + "/data/spot.obj", {}, &local).ok());
  // The typed fields carry the whole report: as core's struct again, it
  // prints what the superseded json field holds, and what a local load
  // prints but for the path and the time taken.
  MeshDiagnostics typed = FromProto(d);
  EXPECT_EQ(typed.ToJson(), d.json());
  EXPECT_EQ(DiagnosticsJsonText(d), d.json());
  EXPECT_THAT(typed.path, HasSubstr("spot.obj"));
  EXPECT_EQ(typed.format, "obj");
  EXPECT_GT(typed.load_seconds, 0);
  typed.path = local.path;
  typed.load_seconds = local.load_seconds;
  EXPECT_EQ(typed.ToJson(), local.ToJson());
  // A server older than the typed fields sent only the JSON (and no format).
  v1::MeshDiagnostics old;
  old.set_vertices(d.vertices());
  old.set_json(d.json());
  EXPECT_EQ(DiagnosticsJsonText(old), d.json());
}

TEST_F(ServiceTest, AFieldStreamsInChunksThatReassembleToTheCoresField) {
  ReadySpot(1e-2);
  grpc::ClientContext ctx;
  v1::DistanceFieldRequest req;
  req.set_mesh("spot");
  req.set_epsilon(1e-2);
  *req.add_sources() = Vertex(7);
  *req.add_sources() = Face(100, 0.2, 0.3, 0.5);
  req.set_nearest_source(true);
  auto reader = stub_->DistanceField(&ctx, req);
  std::vector<double> values;
  std::vector<uint32_t> labels;
  v1::DistanceFieldChunk chunk;
  int chunks = 0;
  while (reader->Read(&chunk)) {
    if (chunks == 0) {
      EXPECT_EQ(chunk.echo().method(), "lc");
      EXPECT_EQ(chunk.echo().epsilon(), 1e-2);
    }
    EXPECT_EQ(chunk.offset(), values.size()) << "chunks arrive in order, without gaps";
    EXPECT_LE(chunk.values_size(), limits_.field_chunk);
    values.insert(values.end(), chunk.values().begin(), chunk.values().end());
    labels.insert(labels.end(), chunk.nearest_source().begin(), chunk.nearest_source().end());
    ++chunks;
  }
  ASSERT_TRUE(reader->Finish().ok());
  EXPECT_EQ(chunks, 3);
  auto engine = Engine(1e-2);
  ASSERT_NE(engine, nullptr);
  FieldOptions options;
  options.nearest_source = true;
  auto want = engine->Field(
      std::vector<SurfacePoint>{SurfacePoint::Vertex(7), SurfacePoint::Face(100, 0.2, 0.3, 0.5)},
      options);
  ASSERT_TRUE(want.ok());
  EXPECT_EQ(values, want->distance);
  EXPECT_EQ(labels, want->nearest_source);
}

// Matrix entries are pair distances (Distance and Matrix answer alike), and
// the echo names the solver that ran.
TEST_F(ServiceTest, MatrixEqualsDistanceAndEchoesItsSolver) {
  ReadySpot(1e-3);
  const std::vector<v1::SurfacePoint> points = {Face(0, 0.2, 0.3, 0.5), Face(0, 0.25, 0.3, 0.45),
                                                Vertex(1500), ToProto(SurfacePoint::Edge(40, 0.3))};
  grpc::ClientContext ctx;
  v1::MatrixRequest req;
  req.set_mesh("spot");
  req.set_epsilon(1e-3);
  for (const auto& p : points) *req.add_sources() = p, *req.add_targets() = p;
  v1::MatrixResponse matrix;
  ASSERT_TRUE(stub_->Matrix(&ctx, req, &matrix).ok());
  EXPECT_EQ(matrix.echo().method(), "lc");
  ASSERT_EQ(matrix.distances_size(), 16);
  grpc::ClientContext pair_ctx;
  v1::DistanceRequest pairs;
  pairs.set_mesh("spot");
  pairs.set_epsilon(1e-3);
  for (const auto& a : points) {
    for (const auto& b : points) {
      auto* p = pairs.add_pairs();
      *p->mutable_from() = a;
      *p->mutable_to() = b;
    }
  }
  v1::DistanceResponse distances;
  ASSERT_TRUE(stub_->Distance(&pair_ctx, pairs, &distances).ok());
  for (int k = 0; k < 16; ++k) {
    const double d = distances.results(k).distance();
    EXPECT_EQ(matrix.distances(k), d) << "entry " << k;
    if (k % 5 == 0) {
      EXPECT_EQ(matrix.distances(k), 0) << "a point's distance to itself";
    }
  }
}

// A MatrixRows stream read to its end: its blocks, and how it finished.
struct Rows {
  std::vector<v1::MatrixRowsChunk> chunks;
  grpc::Status status;
};

Rows ReadRows(v1::Geodesic::Stub& stub, const v1::MatrixRequest& req) {
  grpc::ClientContext ctx;
  auto reader = stub.MatrixRows(&ctx, req);
  Rows rows;
  v1::MatrixRowsChunk chunk;
  while (reader->Read(&chunk)) rows.chunks.push_back(chunk);
  rows.status = reader->Finish();
  return rows;
}

// Every block's bytes in one field, in order, each block checked to hold
// whole rows of the request's width.
template <typename T>
std::vector<T> Packed(const Rows& rows, size_t cols) {
  std::vector<T> out;
  for (const auto& c : rows.chunks) {
    EXPECT_EQ(c.first_row(), out.size() / cols);
    EXPECT_EQ(c.distances_size(), 0) << "packed rows leave distances empty";
    EXPECT_EQ(c.packed().size(), size_t{c.rows()} * cols * sizeof(T));
    const size_t at = out.size();
    out.resize(at + c.packed().size() / sizeof(T));
    std::memcpy(out.data() + at, c.packed().data(), c.packed().size());
  }
  return out;
}

// Packed float64 rows are the repeated doubles' bytes, float32 ones those
// doubles rounded to nearest; `all_targets` is the list of every vertex;
// sparse rows hold exactly the dense entries within the radius. Rows span
// several blocks, each of whole rows.
TEST_F(ServiceTest, MatrixRowsPackDenseAndSparseRowsAsTheDoublesBitForBit) {
  ReadySpot(1e-2);
  v1::MatrixRequest req;
  req.set_mesh("spot");
  req.set_epsilon(1e-2);
  std::vector<SurfacePoint> sources, all;
  for (uint32_t v = 0; v < 400; ++v) {
    sources.push_back(SurfacePoint::Vertex(v * 7));
    *req.add_sources() = Vertex(v * 7);
  }
  for (uint32_t v = 0; v < 2930; ++v) all.push_back(SurfacePoint::Vertex(v));
  req.set_all_targets(true);  // past --max-pairs (50): streamed rows are not held to it
  const size_t cols = all.size();

  const Rows legacy = ReadRows(*stub_, req);
  ASSERT_TRUE(legacy.status.ok()) << legacy.status.error_message();
  ASSERT_GT(legacy.chunks.size(), 1u);
  std::vector<double> want;
  for (const auto& c : legacy.chunks) {
    EXPECT_EQ(c.dtype(), v1::MATRIX_DTYPE_DEFAULT);
    EXPECT_EQ(c.cols(), cols);
    EXPECT_EQ(c.total_rows(), sources.size());
    EXPECT_TRUE(c.packed().empty());
    want.insert(want.end(), c.distances().begin(), c.distances().end());
  }
  ASSERT_EQ(want.size(), sources.size() * cols);
  for (double d : want) ASSERT_TRUE(std::isfinite(d)) << "spot is one component";
  auto engine = Engine(1e-2);
  ASSERT_NE(engine, nullptr);
  auto explicit_all = engine->Matrix(sources, all);
  ASSERT_TRUE(explicit_all.ok()) << explicit_all.status();
  EXPECT_TRUE(*explicit_all == want) << "all_targets differs from every vertex listed";

  req.set_dtype(v1::MATRIX_DTYPE_FLOAT64);
  const Rows f64 = ReadRows(*stub_, req);
  ASSERT_TRUE(f64.status.ok()) << f64.status.error_message();
  for (const auto& c : f64.chunks) EXPECT_EQ(c.dtype(), v1::MATRIX_DTYPE_FLOAT64);
  const std::vector<double> packed64 = Packed<double>(f64, cols);
  ASSERT_EQ(packed64.size(), want.size());
  EXPECT_EQ(std::memcmp(packed64.data(), want.data(), want.size() * sizeof(double)), 0);

  req.set_dtype(v1::MATRIX_DTYPE_FLOAT32);
  const Rows f32 = ReadRows(*stub_, req);
  ASSERT_TRUE(f32.status.ok()) << f32.status.error_message();
  EXPECT_LT(f32.chunks.size(), f64.chunks.size()) << "float32 blocks hold twice the rows";
  const std::vector<float> packed32 = Packed<float>(f32, cols);
  ASSERT_EQ(packed32.size(), want.size());
  std::vector<float> rounded(want.begin(), want.end());
  EXPECT_EQ(std::memcmp(packed32.data(), rounded.data(), rounded.size() * sizeof(float)), 0);

  // A radius that keeps about a tenth of the entries, the zeros included.
  std::vector<double> sorted = want;
  std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 10, sorted.end());
  const double radius = sorted[sorted.size() / 10];
  ASSERT_GT(radius, 0);
  for (v1::MatrixDtype dtype : {v1::MATRIX_DTYPE_DEFAULT, v1::MATRIX_DTYPE_FLOAT32}) {
    const bool narrow = dtype == v1::MATRIX_DTYPE_FLOAT32;
    req.set_dtype(dtype);
    req.set_radius(radius);
    const Rows sparse = ReadRows(*stub_, req);
    ASSERT_TRUE(sparse.status.ok()) << sparse.status.error_message();
    ASSERT_GT(sparse.chunks.size(), 1u);
    size_t row = 0, kept = 0;
    for (const auto& c : sparse.chunks) {
      EXPECT_EQ(c.dtype(), narrow ? v1::MATRIX_DTYPE_FLOAT32 : v1::MATRIX_DTYPE_FLOAT64);
      EXPECT_EQ(c.first_row(), row);
      EXPECT_TRUE(c.packed().empty());
      EXPECT_EQ(c.distances_size(), 0);
      ASSERT_EQ(c.indptr().size(), (c.rows() + 1) * sizeof(uint64_t));
      std::vector<uint64_t> indptr(c.rows() + 1);
      std::memcpy(indptr.data(), c.indptr().data(), c.indptr().size());
      ASSERT_EQ(indptr[0], 0u);
      ASSERT_EQ(c.indices().size(), indptr.back() * sizeof(uint32_t));
      ASSERT_EQ(c.values().size(), indptr.back() * (narrow ? sizeof(float) : sizeof(double)));
      for (size_t k = 0; k < c.rows(); ++k, ++row) {
        std::vector<uint32_t> got_cols, want_cols;
        std::vector<double> got_values, want_values;
        for (uint64_t e = indptr[k]; e < indptr[k + 1]; ++e) {
          uint32_t column;
          std::memcpy(&column, c.indices().data() + e * sizeof column, sizeof column);
          got_cols.push_back(column);
          if (narrow) {
            float value;
            std::memcpy(&value, c.values().data() + e * sizeof value, sizeof value);
            got_values.push_back(value);
          } else {
            double value;
            std::memcpy(&value, c.values().data() + e * sizeof value, sizeof value);
            got_values.push_back(value);
          }
        }
        for (size_t j = 0; j < cols; ++j) {
          const double d = want[row * cols + j];
          if (d > radius) continue;
          want_cols.push_back(static_cast<uint32_t>(j));
          want_values.push_back(narrow ? double(static_cast<float>(d)) : d);
        }
        ASSERT_FALSE(want_cols.empty()) << "row " << row << " keeps at least its own zero";
        ASSERT_EQ(got_cols, want_cols) << "row " << row;
        ASSERT_EQ(got_values, want_values) << "row " << row;
        kept += got_cols.size();
      }
    }
    EXPECT_EQ(row, sources.size());
    EXPECT_GT(kept, want.size() / 20);
    EXPECT_LT(kept, want.size() / 5);
  }
}

// Matrix answers packed bytes too; `all` selectors stand for every vertex
// and count as such against Matrix's limits; radius, dtype and conflicting
// selectors are refused with the value named.
TEST_F(ServiceTest, MatrixSelectorsRadiusAndDtypeAreCheckedAndNamed) {
  ReadySpot(1e-2);
  v1::MatrixRequest base;
  base.set_mesh("spot");
  base.set_epsilon(1e-2);
  *base.add_sources() = Vertex(3);
  *base.add_sources() = Face(0, 0.2, 0.3, 0.5);
  for (uint32_t t : {0, 100, 2000}) *base.add_targets() = Vertex(t);
  auto unary = [&](const v1::MatrixRequest& req, v1::MatrixResponse* resp) {
    grpc::ClientContext ctx;
    return stub_->Matrix(&ctx, req, resp);
  };
  v1::MatrixResponse legacy;
  ASSERT_TRUE(unary(base, &legacy).ok());
  ASSERT_EQ(legacy.distances_size(), 6);
  EXPECT_TRUE(legacy.packed().empty());
  for (v1::MatrixDtype dtype : {v1::MATRIX_DTYPE_FLOAT32, v1::MATRIX_DTYPE_FLOAT64}) {
    v1::MatrixRequest req = base;
    req.set_dtype(dtype);
    v1::MatrixResponse packed;
    ASSERT_TRUE(unary(req, &packed).ok());
    EXPECT_EQ(packed.dtype(), dtype);
    EXPECT_EQ(packed.distances_size(), 0);
    for (int k = 0; k < 6; ++k) {
      ASSERT_TRUE(std::isfinite(legacy.distances(k)));
      if (dtype == v1::MATRIX_DTYPE_FLOAT32) {
        ASSERT_EQ(packed.packed().size(), 6 * sizeof(float));
        float value;
        std::memcpy(&value, packed.packed().data() + k * sizeof value, sizeof value);
        EXPECT_EQ(value, static_cast<float>(legacy.distances(k))) << "entry " << k;
      } else {
        ASSERT_EQ(packed.packed().size(), 6 * sizeof(double));
        double value;
        std::memcpy(&value, packed.packed().data() + k * sizeof value, sizeof value);
        EXPECT_EQ(value, legacy.distances(k)) << "entry " << k;
      }
    }
  }

  // all_sources streams every vertex's row, past Matrix's row limit.
  {
    v1::MatrixRequest req = base;
    req.clear_sources();
    req.set_all_sources(true);
    req.set_dtype(v1::MATRIX_DTYPE_FLOAT64);
    const Rows rows = ReadRows(*stub_, req);
    ASSERT_TRUE(rows.status.ok()) << rows.status.error_message();
    const std::vector<double> got = Packed<double>(rows, 3);
    ASSERT_EQ(got.size(), 2930u * 3);
    EXPECT_EQ(got[3 * 3], legacy.distances(0)) << "row 3 is vertex 3's";
    EXPECT_EQ(got[100 * 3 + 1], 0);
  }

  auto expect_refused = [&](const v1::MatrixRequest& req, grpc::StatusCode code,
                            const std::string& message) {
    v1::MatrixResponse resp;
    grpc::Status s = unary(req, &resp);
    EXPECT_EQ(s.error_code(), code) << s.error_message();
    EXPECT_THAT(s.error_message(), HasSubstr(message));
    if (req.radius() != 0 && std::isfinite(req.radius()) && req.radius() > 0) return;
    const Rows rows = ReadRows(*stub_, req);
    if (code == grpc::StatusCode::RESOURCE_EXHAUSTED) {
      EXPECT_TRUE(rows.status.ok()) << "MatrixRows streams `all`: " << rows.status.error_message();
      return;
    }
    EXPECT_EQ(rows.status.error_code(), code) << rows.status.error_message();
    EXPECT_THAT(rows.status.error_message(), HasSubstr(message));
  };
  for (double radius : {-1.0, std::nan(""), std::numeric_limits<double>::infinity()}) {
    v1::MatrixRequest req = base;
    req.set_radius(radius);
    expect_refused(req, grpc::StatusCode::INVALID_ARGUMENT,
                   absl::StrCat("radius ", std::isnan(radius)   ? "nan"
                                           : std::isinf(radius) ? "inf"
                                                                : "-1"));
  }
  {
    v1::MatrixRequest req = base;
    req.set_radius(0.5);
    expect_refused(req, grpc::StatusCode::INVALID_ARGUMENT, "only MatrixRows");
  }
  {
    v1::MatrixRequest req = base;
    req.set_all_sources(true);
    expect_refused(req, grpc::StatusCode::INVALID_ARGUMENT,
                   "all_sources and 2 explicit sources: give one or the other");
    req = base;
    req.set_all_targets(true);
    expect_refused(req, grpc::StatusCode::INVALID_ARGUMENT, "all_targets and 3 explicit targets");
    req = base;
    req.set_dtype(static_cast<v1::MatrixDtype>(7));
    expect_refused(req, grpc::StatusCode::INVALID_ARGUMENT, "dtype 7");
    req = base;
    req.clear_targets();
    req.set_all_targets(true);
    expect_refused(req, grpc::StatusCode::RESOURCE_EXHAUSTED,
                   "matrix of 2 x 2930 exceeds the limits (1024 sources, 50 targets)");
  }
}

// A client that goes away mid-stream stops the rows being computed: the
// query leaves admission within moments, not after the whole matrix.
TEST_F(ServiceTest, MatrixRowsStopWhenTheClientGoesAway) {
  ReadySpot(1e-2);
  v1::MatrixRequest req;
  req.set_mesh("spot");
  req.set_epsilon(1e-2);
  req.set_all_sources(true);
  req.set_all_targets(true);
  req.set_dtype(v1::MATRIX_DTYPE_FLOAT32);
  const auto start = std::chrono::steady_clock::now();
  std::chrono::steady_clock::duration first_block;
  {
    grpc::ClientContext ctx;
    auto reader = stub_->MatrixRows(&ctx, req);
    v1::MatrixRowsChunk chunk;
    ASSERT_TRUE(reader->Read(&chunk));
    first_block = std::chrono::steady_clock::now() - start;
    EXPECT_EQ(chunk.total_rows(), 2930u);
    // Several blocks to go. The block under way when the client leaves takes
    // about as long as the first: the rows stop within it, not after it.
    ASSERT_LT(chunk.rows() * 5, 2930u);
    ctx.TryCancel();
    EXPECT_EQ(reader->Finish().error_code(), grpc::StatusCode::CANCELLED);
  }
  const auto cancelled = std::chrono::steady_clock::now();
  while (service_->admission().running() > 0 &&
         std::chrono::steady_clock::now() < cancelled + std::chrono::seconds(30)) {
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  EXPECT_EQ(service_->admission().running(), 0);
  EXPECT_LT(std::chrono::steady_clock::now() - cancelled, first_block / 2)
      << "the rows went on after the client left";
}

// exact: the exact engine's distances for pairs and matrix rows, marked
// exact; past --max-exact-bytes the call is refused and the server goes on.
TEST_F(ServiceTest, ExactPairsAndRowsAreTheExactEnginesAndKeepToTheirLimit) {
  ReadySpot(1e-2);
  const SurfacePoint from = SurfacePoint::Face(0, 0.2, 0.3, 0.5);
  const std::vector<uint32_t> targets = {1500, 700};
  ExactGeodesic exact(Engine(1e-2)->mesh());
  auto truth = exact.Distances(from);
  ASSERT_TRUE(truth.ok()) << truth.status();
  v1::DistanceRequest pairs;
  *pairs.mutable_graph() = MakeSelector("spot", 1e-2, false);
  pairs.set_exact(true);
  v1::MatrixRequest rows;
  *rows.mutable_graph() = MakeSelector("spot", 1e-2, false);
  rows.set_exact(true);
  *rows.add_sources() = ToProto(from);
  for (uint32_t t : targets) {
    auto* p = pairs.add_pairs();
    *p->mutable_from() = ToProto(from);
    *p->mutable_to() = Vertex(t);
    *rows.add_targets() = Vertex(t);
  }
  grpc::ClientContext ctx;
  v1::DistanceResponse answer;
  ASSERT_TRUE(stub_->Distance(&ctx, pairs, &answer).ok());
  EXPECT_EQ(answer.echo().method(), "exact");
  grpc::ClientContext matrix_ctx;
  v1::MatrixResponse matrix;
  ASSERT_TRUE(stub_->Matrix(&matrix_ctx, rows, &matrix).ok());
  ASSERT_EQ(answer.results_size(), 2);
  ASSERT_EQ(matrix.distances_size(), 2);
  for (int k = 0; k < 2; ++k) {
    const double want = (*truth)[targets[k]];
    ASSERT_TRUE(std::isfinite(want) && std::isfinite(answer.results(k).distance()));
    EXPECT_TRUE(answer.results(k).exact());
    EXPECT_NEAR(answer.results(k).distance(), want, 1e-12 * want) << "pair " << k;
    EXPECT_NEAR(matrix.distances(k), want, 1e-12 * want) << "entry " << k;
  }

  ServiceLimits tight = limits_;
  tight.max_exact_bytes = 1;
  GeodesicService small(registry_.get(), cache_.get(), &metrics_, tight);
  grpc::ServerBuilder builder;
  int port = 0;
  builder.AddListeningPort("127.0.0.1:0", grpc::InsecureServerCredentials(), &port);
  builder.RegisterService(&small);
  auto server = builder.BuildAndStart();
  ASSERT_NE(server, nullptr);
  auto stub = v1::Geodesic::NewStub(
      grpc::CreateChannel(absl::StrCat("127.0.0.1:", port), grpc::InsecureChannelCredentials()));
  grpc::ClientContext refused_ctx;
  v1::DistanceResponse refused;
  const grpc::Status status = stub->Distance(&refused_ctx, pairs, &refused);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_THAT(status.error_message(), ::testing::HasSubstr("over its limit"));
  grpc::ClientContext plain_ctx;
  pairs.set_exact(false);
  v1::DistanceResponse plain;
  ASSERT_TRUE(stub->Distance(&plain_ctx, pairs, &plain).ok());
  EXPECT_FALSE(plain.results(0).exact());
  server->Shutdown();
}

TEST_F(ServiceTest, BadRequestsGetCodesThatNameTheProblem) {
  ReadySpot(1e-2);
  auto distance = [&](v1::SurfacePoint a, v1::SurfacePoint b, const std::string& mesh, double eps) {
    grpc::ClientContext ctx;
    v1::DistanceRequest req;
    req.set_mesh(mesh);
    req.set_epsilon(eps);
    *req.add_pairs()->mutable_from() = a;
    *req.mutable_pairs(0)->mutable_to() = b;
    v1::DistanceResponse resp;
    return stub_->Distance(&ctx, req, &resp);
  };
  grpc::Status s = distance(Vertex(99999), Vertex(1), "spot", 1e-2);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::OUT_OF_RANGE);
  EXPECT_THAT(s.error_message(), HasSubstr("pair 0, from"));
  s = distance(Face(3, 0.5, 0.6, 0.1), Vertex(1), "spot", 1e-2);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  s = distance(Vertex(0), Vertex(1), "nosuch", 1e-2);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::NOT_FOUND);
  // Never requested, and not the default epsilon: no query starts it.
  s = distance(Vertex(0), Vertex(1), "spot", 0.02);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  EXPECT_THAT(s.error_message(), HasSubstr("RequestGraph"));
  EXPECT_THAT(s.error_message(), HasSubstr("--auto-build-any-epsilon"));
  s = distance(Vertex(0), Vertex(1), "spot", std::nan(""));
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  grpc::ClientContext ctx;
  v1::DistanceRequest many;
  many.set_mesh("spot");
  for (int i = 0; i <= limits_.max_pairs; ++i) *many.add_pairs()->mutable_from() = Vertex(i);
  v1::DistanceResponse resp;
  EXPECT_EQ(stub_->Distance(&ctx, many, &resp).error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  // The limit rides as a trailer, for clients that split their batches.
  const auto& trailers = ctx.GetServerTrailingMetadata();
  auto limit = trailers.find("limit-max-pairs");
  ASSERT_NE(limit, trailers.end());
  EXPECT_EQ(std::string(limit->second.data(), limit->second.size()), "50");
  // And it still answers.
  EXPECT_TRUE(distance(Vertex(0), Vertex(1), "spot", 1e-2).ok());
}

TEST_F(ServiceTest, AQueryStartsTheGraphItNeedsUnlessTheOperatorSaysNo) {
  TearDown();
  limits_.default_epsilon = 0.03;
  SetUp();
  ReadySpot(1e-2);  // registers spot
  // The first query on the default graph, which nobody requested, builds it
  // and answers.
  grpc::ClientContext ctx;
  v1::DistanceRequest req;
  req.set_mesh("spot");
  req.set_epsilon(0.03);
  req.add_pairs()->mutable_from()->set_vertex(0);
  req.mutable_pairs(0)->mutable_to()->set_vertex(1500);
  v1::DistanceResponse first;
  ASSERT_TRUE(stub_->Distance(&ctx, req, &first).ok());
  ASSERT_EQ(first.results_size(), 1);
  EXPECT_TRUE(std::isfinite(first.results(0).distance()) && first.results(0).distance() > 0);
  grpc::ClientContext get_ctx;
  v1::GetGraphRequest get;
  get.set_mesh("spot");
  get.set_epsilon(0.03);
  v1::Graph graph;
  ASSERT_TRUE(stub_->GetGraph(&get_ctx, get, &graph).ok());
  EXPECT_EQ(graph.state(), v1::GRAPH_STATE_READY);

  // Another epsilon starts a graph only when the operator allows any.
  v1::DistanceRequest other = req;
  other.set_epsilon(0.05);
  {
    grpc::ClientContext other_ctx;
    grpc::Status s = stub_->Distance(&other_ctx, other, &first);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
    EXPECT_THAT(s.error_message(), HasSubstr("RequestGraph"));
  }
  TearDown();
  limits_.auto_build_any_epsilon = true;
  SetUp();
  ReadySpot(1e-2);
  {
    grpc::ClientContext other_ctx;
    EXPECT_TRUE(stub_->Distance(&other_ctx, other, &first).ok());
  }

  // An operator who builds every graph ahead turns that off.
  TearDown();
  limits_.build_on_query = false;
  SetUp();
  ReadySpot(1e-2);
  grpc::ClientContext off_ctx;
  v1::DistanceResponse refused;
  grpc::Status s = stub_->Distance(&off_ctx, req, &refused);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  EXPECT_THAT(s.error_message(), HasSubstr("eps 0.03"));
}

TEST_F(ServiceTest, ExactPairsAndSamplesPastTheirCapsAreRefusedNamingTheFlag) {
  TearDown();
  limits_.max_exact_pairs = 4;
  limits_.max_samples = 3;
  SetUp();
  ReadySpot(1e-2);
  auto exact = [&](int pairs) {
    grpc::ClientContext ctx;
    v1::DistanceRequest req;
    req.mutable_graph()->set_mesh("spot");
    req.mutable_graph()->set_epsilon(1e-2);
    req.set_exact(true);
    for (int i = 0; i < pairs; ++i) {
      *req.add_pairs()->mutable_from() = Vertex(i);
      *req.mutable_pairs(i)->mutable_to() = Vertex(1500 + i);
    }
    v1::DistanceResponse resp;
    return stub_->Distance(&ctx, req, &resp);
  };
  grpc::Status s = exact(5);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_THAT(s.error_message(), HasSubstr("--max-exact-pairs"));
  EXPECT_TRUE(exact(4).ok());
  auto sample = [&](uint32_t count) {
    grpc::ClientContext ctx;
    v1::SamplePointsRequest req;
    req.mutable_graph()->set_mesh("spot");
    req.mutable_graph()->set_epsilon(1e-2);
    req.set_count(count);
    v1::SamplePointsResponse resp;
    return stub_->SamplePoints(&ctx, req, &resp);
  };
  s = sample(4);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_THAT(s.error_message(), HasSubstr("--max-samples"));
  EXPECT_TRUE(sample(3).ok());
}

TEST_F(ServiceTest, ALightQueryRunsBetweenTheSlicesOfAnotherClientsExactBatch) {
  TearDown();
  limits_.query_threads = 1;
  limits_.max_pairs = limits_.max_exact_pairs;
  SetUp();
  ReadySpot(1e-2);
  // Two clients on one host: their tokens tell them apart.
  service_->RequireBearerTokens({"heavy", "light"});
  auto call = [&](const std::string& token, bool exact, int pairs) {
    grpc::ClientContext ctx;
    ctx.AddMetadata("authorization", "Bearer " + token);
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(120));
    v1::DistanceRequest req;
    req.mutable_graph()->set_mesh("spot");
    req.mutable_graph()->set_epsilon(1e-2);
    req.set_exact(exact);
    for (int i = 0; i < pairs; ++i) {
      *req.add_pairs()->mutable_from() = Vertex(i * 7);
      *req.mutable_pairs(i)->mutable_to() = Vertex((i * 7 + 1465) % 2930);
    }
    v1::DistanceResponse resp;
    return stub_->Distance(&ctx, req, &resp);
  };
  absl::Duration heavy_took;
  std::thread heavy([&] {
    const absl::Time start = absl::Now();
    const grpc::Status s = call("heavy", true, limits_.max_exact_pairs);
    EXPECT_TRUE(s.ok()) << s.error_message();
    heavy_took = absl::Now() - start;
  });
  while (service_->admission().running() == 0) absl::SleepFor(absl::Milliseconds(1));
  // The one slot is the heavy batch's: the light query waits for a slice's
  // end, not for the batch's.
  const absl::Time start = absl::Now();
  EXPECT_TRUE(call("light", false, 1).ok());
  const absl::Duration light_took = absl::Now() - start;
  heavy.join();
  EXPECT_LT(light_took, heavy_took / 2) << "heavy " << heavy_took;
}

TEST_F(ServiceTest, ANegativeOrNanMaxDistanceIsRefused) {
  ReadySpot(1e-2);
  for (double bad : {-1.0, std::nan("")}) {
    grpc::ClientContext ctx;
    v1::DistanceFieldRequest req;
    req.mutable_graph()->set_mesh("spot");
    req.mutable_graph()->set_epsilon(1e-2);
    *req.add_sources() = Vertex(0);
    req.set_max_distance(bad);
    auto reader = stub_->DistanceField(&ctx, req);
    v1::DistanceFieldChunk chunk;
    while (reader->Read(&chunk)) {
    }
    grpc::Status s = reader->Finish();
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << bad;
    EXPECT_THAT(s.error_message(), HasSubstr("max_distance"));
  }
}

TEST_F(ServiceTest, TheBuildBudgetBoundsNewGraphsPerClientAndInAll) {
  TearDown();
  limits_.max_queued_builds = 3;
  limits_.max_queued_builds_per_client = 2;
  SetUp();
  ReadySpot(1e-2);
  // Clients on one host: their tokens tell them apart.
  service_->RequireBearerTokens({"a", "b", "c"});
  auto request = [&](const std::string& token, double eps, double max_error = 0) {
    grpc::ClientContext ctx;
    if (!token.empty()) ctx.AddMetadata("authorization", "Bearer " + token);
    v1::RequestGraphRequest req;
    req.mutable_graph()->set_mesh("spot");
    req.mutable_graph()->set_epsilon(eps);
    req.mutable_graph()->set_max_error(max_error);
    v1::Graph graph;
    return stub_->RequestGraph(&ctx, req, &graph);
  };
  grpc::Status s = request("c", 1e-5);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(s.error_message(), HasSubstr("--min-epsilon"));
  EXPECT_THAT(s.error_message(), HasSubstr("estimated at"));
  s = request("c", 0, 1e-4);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(s.error_message(), HasSubstr("--min-max-error"));
  // Builds long enough to stay queued while the test asks.
  EXPECT_TRUE(request("a", 2e-4).ok());
  EXPECT_TRUE(request("a", 2.1e-4).ok());
  s = request("a", 2.2e-4);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_THAT(s.error_message(), HasSubstr("--max-queued-builds-per-client"));
  // Joining a graph being made adds no build.
  EXPECT_TRUE(request("b", 2e-4).ok());
  EXPECT_TRUE(request("b", 2.3e-4).ok());
  s = request("c", 2.4e-4);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_THAT(s.error_message(), HasSubstr("--max-queued-builds"));
  for (double eps : {2e-4, 2.1e-4, 2.3e-4}) {
    grpc::ClientContext ctx;
    v1::CancelGraphRequest req;
    req.mutable_graph()->set_mesh("spot");
    req.mutable_graph()->set_epsilon(eps);
    v1::Graph graph;
    stub_->CancelGraph(&ctx, req, &graph);
  }
}

TEST_F(ServiceTest, ThePseudoVertexGraphIsItsOwnGraph) {
  ReadySpot(2e-2);
  ReadySpot(2e-2, /*pseudo=*/true);
  grpc::ClientContext ctx;
  v1::ListGraphsResponse list;
  ASSERT_TRUE(stub_->ListGraphs(&ctx, {}, &list).ok());
  ASSERT_EQ(list.graphs_size(), 2);
  EXPECT_NE(list.graphs(0).pseudo_vertices(), list.graphs(1).pseudo_vertices());
  grpc::ClientContext pair_ctx;
  v1::DistanceRequest req;
  req.set_mesh("spot");
  req.set_epsilon(2e-2);
  req.set_pseudo_vertices(true);
  *req.add_pairs()->mutable_from() = Vertex(0);
  *req.mutable_pairs(0)->mutable_to() = Vertex(2000);
  v1::DistanceResponse resp;
  ASSERT_TRUE(stub_->Distance(&pair_ctx, req, &resp).ok());
  EXPECT_TRUE(resp.echo().pseudo_vertices());
}

TEST_F(ServiceTest, ACertifiedGraphIsItsOwnGraphWithASoundCertificate) {
  ReadySpot(CertifiedKeyEpsilon(1e-2));  // the plain graph of the first build's epsilon
  v1::GraphSelector certified = MakeSelector("spot", 0, false);
  certified.set_max_error(1e-2);
  {
    grpc::ClientContext ctx;
    v1::RequestGraphRequest req;
    *req.mutable_graph() = certified;
    v1::Graph started;
    ASSERT_TRUE(stub_->RequestGraph(&ctx, req, &started).ok());
    EXPECT_EQ(started.max_error(), 1e-2);
    EXPECT_FALSE(started.has_certificate());
  }
  grpc::ClientContext ctx;
  v1::GetGraphRequest get;
  *get.mutable_graph() = certified;
  auto watch = stub_->WatchGraph(&ctx, get);
  v1::Graph last;
  std::set<std::string> phases;
  while (watch->Read(&last)) phases.insert(last.phase());
  ASSERT_TRUE(watch->Finish().ok());
  ASSERT_EQ(last.state(), v1::GRAPH_STATE_READY) << last.error();
  ASSERT_TRUE(last.has_certificate());
  const v1::GraphCertificate& c = last.certificate();
  EXPECT_TRUE(c.sound());
  EXPECT_EQ(c.max_error_bound(), 1e-2);
  EXPECT_LE(c.measured_max_error(), 1e-2);
  EXPECT_GT(c.measured_max_error(), 0);
  EXPECT_LE(c.measured_mean_error(), c.measured_max_error());
  EXPECT_LT(c.epsilon(), 1e-2);
  EXPECT_GT(c.sources(), 0u);
  EXPECT_GE(c.builds(), 1u);
  EXPECT_EQ(last.epsilon(), c.epsilon());
  EXPECT_EQ(last.max_error(), 1e-2);

  // Beside the plain graph, never it: a plain request at the certified
  // graph's epsilon names the plain graph (or none), with no certificate.
  grpc::ClientContext list_ctx;
  v1::ListGraphsResponse list;
  ASSERT_TRUE(stub_->ListGraphs(&list_ctx, {}, &list).ok());
  ASSERT_EQ(list.graphs_size(), 2);
  EXPECT_NE(list.graphs(0).has_certificate(), list.graphs(1).has_certificate());
  grpc::ClientContext plain_ctx;
  v1::GetGraphRequest plain;
  *plain.mutable_graph() = MakeSelector("spot", CertifiedKeyEpsilon(1e-2), false);
  v1::Graph plain_graph;
  ASSERT_TRUE(stub_->GetGraph(&plain_ctx, plain, &plain_graph).ok());
  EXPECT_FALSE(plain_graph.has_certificate());
  EXPECT_EQ(plain_graph.max_error(), 0);

  // A query that names the bound is answered by the certified graph, and
  // its echo says so, with the epsilon it was built with.
  grpc::ClientContext pair_ctx;
  v1::DistanceRequest req;
  *req.mutable_graph() = certified;
  *req.add_pairs()->mutable_from() = Vertex(0);
  *req.mutable_pairs(0)->mutable_to() = Vertex(2000);
  v1::DistanceResponse resp;
  ASSERT_TRUE(stub_->Distance(&pair_ctx, req, &resp).ok());
  EXPECT_EQ(resp.echo().graph().max_error(), 1e-2);
  EXPECT_EQ(resp.echo().graph().epsilon(), c.epsilon());
  auto engine = cache_->Acquire({"spot",
                                 [] {
                                   DggParams p;
                                   p.epsilon = CertifiedKeyEpsilon(1e-2);
                                   return p;
                                 }(),
                                 1e-2});
  ASSERT_TRUE(engine.ok()) << engine.status();
  auto want = (*engine)->Distances(std::vector{SurfacePoint::Vertex(0)},
                                   std::vector{SurfacePoint::Vertex(2000)}, {});
  ASSERT_TRUE(want.ok());
  EXPECT_NEAR(resp.results(0).distance(), (*want)[0].distance, 1e-9 * (*want)[0].distance);

  // A bound outside what the server certifies is refused.
  grpc::ClientContext bad_ctx;
  v1::RequestGraphRequest bad;
  *bad.mutable_graph() = certified;
  bad.mutable_graph()->set_max_error(2);
  v1::Graph unused;
  grpc::Status refused = stub_->RequestGraph(&bad_ctx, bad, &unused);
  EXPECT_EQ(refused.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(refused.error_message(), HasSubstr("max_error"));
}

// How a request names spot's graph at 2e-2 with pseudo vertices: in the
// fields that `graph` superseded, in `graph` alone, or in `graph` while
// those fields name another graph (of no mesh, at another epsilon, plain).
enum class Naming { kOldFields, kGraph, kBoth };

template <typename Request>
void NameGraph(Naming naming, Request* req) {
  if (naming != Naming::kGraph) {
    const bool other = naming == Naming::kBoth;
    req->set_mesh(other ? "nosuch" : "spot");
    req->set_epsilon(other ? 0.3 : 2e-2);
    req->set_pseudo_vertices(!other);
  }
  if (naming != Naming::kOldFields) *req->mutable_graph() = MakeSelector("spot", 2e-2, true);
}

// The echo names the graph in `graph` and, for clients from before it, in
// the fields it superseded.
void ExpectEchoOfPseudoGraph(const v1::QueryEcho& echo, const std::string& what) {
  EXPECT_EQ(echo.graph().mesh(), "spot") << what;
  EXPECT_EQ(echo.graph().epsilon(), 2e-2) << what;
  EXPECT_TRUE(echo.graph().pseudo_vertices()) << what;
  EXPECT_EQ(echo.mesh(), "spot") << what;
  EXPECT_EQ(echo.epsilon(), 2e-2) << what;
  EXPECT_TRUE(echo.pseudo_vertices()) << what;
}

void ExpectPseudoGraph(const v1::Graph& g, const std::string& what) {
  EXPECT_EQ(g.mesh(), "spot") << what;
  EXPECT_EQ(g.epsilon(), 2e-2) << what;
  EXPECT_TRUE(g.pseudo_vertices()) << what;
  EXPECT_EQ(g.state(), v1::GRAPH_STATE_READY) << what;
}

// Every request that names a graph: `graph` alone selects the graph the old
// fields alone select, and with both set, `graph` wins.
TEST_F(ServiceTest, GraphSelectorSelectsAsTheOldFieldsDoAndWinsOverThem) {
  ReadySpot(2e-2);
  ReadySpot(2e-2, /*pseudo=*/true);
  std::vector<double> distances;
  std::vector<std::vector<uint32_t>> samples;
  for (Naming naming : {Naming::kOldFields, Naming::kGraph, Naming::kBoth}) {
    const std::string what = absl::StrCat("naming ", static_cast<int>(naming));
    v1::Graph g;
    {
      grpc::ClientContext ctx;
      v1::RequestGraphRequest req;
      NameGraph(naming, &req);
      ASSERT_TRUE(stub_->RequestGraph(&ctx, req, &g).ok()) << what;
      ExpectPseudoGraph(g, "RequestGraph, " + what);
    }
    {
      grpc::ClientContext ctx;
      v1::GetGraphRequest req;
      NameGraph(naming, &req);
      ASSERT_TRUE(stub_->GetGraph(&ctx, req, &g).ok()) << what;
      ExpectPseudoGraph(g, "GetGraph, " + what);
      grpc::ClientContext watch_ctx;
      auto watch = stub_->WatchGraph(&watch_ctx, req);
      ASSERT_TRUE(watch->Read(&g)) << what;
      ExpectPseudoGraph(g, "WatchGraph, " + what);
      while (watch->Read(&g)) {
      }
      ASSERT_TRUE(watch->Finish().ok()) << what;
    }
    {
      grpc::ClientContext ctx;
      v1::CancelGraphRequest req;  // a ready graph has nothing to cancel
      NameGraph(naming, &req);
      ASSERT_TRUE(stub_->CancelGraph(&ctx, req, &g).ok()) << what;
      ExpectPseudoGraph(g, "CancelGraph, " + what);
    }
    {
      grpc::ClientContext ctx;
      v1::DistanceRequest req;
      NameGraph(naming, &req);
      *req.add_pairs()->mutable_from() = Vertex(0);
      *req.mutable_pairs(0)->mutable_to() = Vertex(2000);
      v1::DistanceResponse resp;
      grpc::Status s = stub_->Distance(&ctx, req, &resp);
      ASSERT_TRUE(s.ok()) << what << ": " << s.error_message();
      ExpectEchoOfPseudoGraph(resp.echo(), "Distance, " + what);
      distances.push_back(resp.results(0).distance());
    }
    {
      grpc::ClientContext ctx;
      v1::MatrixRequest req;
      NameGraph(naming, &req);
      *req.add_sources() = Vertex(0);
      *req.add_targets() = Vertex(2000);
      v1::MatrixResponse resp;
      ASSERT_TRUE(stub_->Matrix(&ctx, req, &resp).ok()) << what;
      ExpectEchoOfPseudoGraph(resp.echo(), "Matrix, " + what);
      grpc::ClientContext rows_ctx;
      auto rows = stub_->MatrixRows(&rows_ctx, req);
      v1::MatrixRowsChunk chunk;
      ASSERT_TRUE(rows->Read(&chunk)) << what;
      ExpectEchoOfPseudoGraph(chunk.echo(), "MatrixRows, " + what);
      while (rows->Read(&chunk)) {
      }
      ASSERT_TRUE(rows->Finish().ok()) << what;
    }
    {
      grpc::ClientContext ctx;
      v1::DistanceFieldRequest req;
      NameGraph(naming, &req);
      *req.add_sources() = Vertex(0);
      req.add_targets(2000);
      auto field = stub_->DistanceField(&ctx, req);
      v1::DistanceFieldChunk chunk;
      ASSERT_TRUE(field->Read(&chunk)) << what;
      ExpectEchoOfPseudoGraph(chunk.echo(), "DistanceField, " + what);
      ASSERT_EQ(chunk.values_size(), 1) << what;
      EXPECT_EQ(chunk.values(0), distances.back()) << what;
      while (field->Read(&chunk)) {
      }
      ASSERT_TRUE(field->Finish().ok()) << what;
    }
    {
      grpc::ClientContext ctx;
      v1::SamplePointsRequest req;
      NameGraph(naming, &req);
      req.set_count(4);
      v1::SamplePointsResponse resp;
      ASSERT_TRUE(stub_->SamplePoints(&ctx, req, &resp).ok()) << what;
      ExpectEchoOfPseudoGraph(resp.echo(), "SamplePoints, " + what);
      samples.emplace_back(resp.vertices().begin(), resp.vertices().end());
    }
  }
  // One graph answered all three namings alike.
  EXPECT_EQ(distances[1], distances[0]);
  EXPECT_EQ(distances[2], distances[0]);
  EXPECT_EQ(samples[1], samples[0]);
  EXPECT_EQ(samples[2], samples[0]);
}

// The rule itself: `graph` counts once it is set, even to its defaults (the
// server's default epsilon, the plain graph); until then the old fields do.
TEST(SelectorOfTest, GraphCountsOnceSetEvenToItsDefaults) {
  v1::SamplePointsRequest req;
  req.set_mesh("old");
  req.set_epsilon(0.1);
  req.set_pseudo_vertices(true);
  v1::GraphSelector graph = SelectorOf(req);
  EXPECT_EQ((std::tuple(graph.mesh(), graph.epsilon(), graph.pseudo_vertices())),
            (std::tuple("old", 0.1, true)));
  req.mutable_graph()->set_mesh("new");
  graph = SelectorOf(req);
  EXPECT_EQ((std::tuple(graph.mesh(), graph.epsilon(), graph.pseudo_vertices())),
            (std::tuple("new", 0.0, false)));
}

TEST_F(ServiceTest, UnloadDropsTheMeshAndItsGraphs) {
  ReadySpot(1e-2);
  {
    grpc::ClientContext ctx;
    v1::UnloadMeshRequest req;
    req.set_name("spot");
    v1::UnloadMeshResponse resp;
    ASSERT_TRUE(stub_->UnloadMesh(&ctx, req, &resp).ok());
  }
  grpc::ClientContext ctx;
  v1::ListGraphsResponse list;
  ASSERT_TRUE(stub_->ListGraphs(&ctx, {}, &list).ok());
  EXPECT_EQ(list.graphs_size(), 0);
  EXPECT_EQ(registry_->Get("spot").status().code(), absl::StatusCode::kNotFound);
}

// The cow without the right half of a band through its body, in the
// parent's vertex ids (as core/region_test.cc cuts it).
std::vector<uint32_t> SpotWithoutBand(const Mesh& spot) {
  std::vector<uint32_t> kept;
  for (VertexId v = 0; v < spot.num_vertices(); ++v) {
    const Vec3& p = spot.position(v);
    if (!(std::abs(p.y - 0.1) < 0.08 && p.x > 0)) kept.push_back(v);
  }
  return kept;
}

// An upload left open holds its declared payload's bytes of --memory-limit:
// a second that cannot fit beside it is refused at once, naming the limit,
// and the bytes come back when the first ends.
TEST_F(ServiceTest, UploadsLeftOpenCountAgainstTheMemoryLimit) {
  MemoryLedger ledger(1'000'000, [this] { return registry_->resident_bytes(); });
  service_->UseMemoryLedger(&ledger);
  // An upload counts the bytes it sent, not those it declared.
  auto first_message = [](const std::string& name, uint64_t declared, uint64_t sent) {
    v1::UploadMeshRequest m;
    m.set_name(name);
    m.set_format("obj");
    m.set_total_bytes(declared);
    m.set_sha256(std::string(64, '0'));
    m.set_data(std::string(sent, ' '));
    return m;
  };
  grpc::ClientContext open_ctx;
  v1::Mesh open_resp;
  auto open = stub_->UploadMesh(&open_ctx, &open_resp);
  ASSERT_TRUE(open->Write(first_message("open", 900'000, 600'000)));
  const absl::Time deadline = absl::Now() + absl::Seconds(10);
  while (ledger.reserved() != 600'000u && absl::Now() < deadline) {
    absl::SleepFor(absl::Milliseconds(10));
  }
  EXPECT_EQ(ledger.reserved(), 600'000u);

  for (const auto& [bytes, code] : std::vector<std::pair<uint64_t, grpc::StatusCode>>{
           {600'000, grpc::StatusCode::UNAVAILABLE},
           {2'000'000, grpc::StatusCode::RESOURCE_EXHAUSTED}}) {
    grpc::ClientContext ctx;
    v1::Mesh resp;
    auto refused = stub_->UploadMesh(&ctx, &resp);
    refused->Write(first_message("second", bytes, bytes));
    refused->WritesDone();
    const grpc::Status status = refused->Finish();
    EXPECT_EQ(status.error_code(), code) << bytes << ": " << status.error_message();
    EXPECT_THAT(status.error_message(), HasSubstr("--memory-limit")) << bytes;
    EXPECT_THAT(status.error_message(), HasSubstr("'second'")) << bytes;
  }
  EXPECT_EQ(ledger.reserved(), 600'000u);

  open_ctx.TryCancel();
  open->Finish();
  while (ledger.reserved() != 0 && absl::Now() < deadline) absl::SleepFor(absl::Milliseconds(10));
  EXPECT_EQ(ledger.reserved(), 0u);
  EXPECT_FALSE(registry_->Get("open").ok());
}

TEST_F(ServiceTest, ARegionIsAMeshOfItsOwnThatRemembersItsParent) {
  ReadySpot(1e-2);
  auto spot = registry_->Get("spot");
  ASSERT_TRUE(spot.ok());
  const std::vector<uint32_t> kept = SpotWithoutBand(*(*spot)->mesh);
  ASSERT_FALSE(kept.empty());
  ASSERT_LT(kept.size(), (*spot)->mesh->num_vertices());
  auto register_region = [&](const std::string& name, const std::string& parent,
                             const std::vector<uint32_t>& vertices,
                             const std::vector<uint32_t>& faces, v1::Mesh* out) {
    grpc::ClientContext ctx;
    v1::RegisterRegionRequest req;
    req.set_name(name);
    req.set_parent(parent);
    for (uint32_t v : vertices) req.add_vertex_ids(v);
    for (uint32_t f : faces) req.add_face_ids(f);
    return stub_->RegisterRegion(&ctx, req, out);
  };
  v1::Mesh region;
  grpc::Status s = register_region("body", "spot", kept, {}, &region);
  ASSERT_TRUE(s.ok()) << s.error_message();
  EXPECT_EQ(region.parent(), "spot");
  EXPECT_EQ(region.parent_vertices(), 2930u);
  EXPECT_EQ(region.parent_faces(), (*spot)->mesh->num_faces());
  EXPECT_GT(region.diagnostics().vertices(), 0u);
  EXPECT_LT(region.diagnostics().vertices(), 2930u);
  EXPECT_NE(region.fingerprint(), absl::StrFormat("%016x", (*spot)->fingerprint));
  // Again, the same: a no-op.
  v1::Mesh again;
  ASSERT_TRUE(register_region("body", "spot", kept, {}, &again).ok());
  EXPECT_EQ(again.fingerprint(), region.fingerprint());
  {
    grpc::ClientContext ctx;
    v1::ListMeshesResponse list;
    ASSERT_TRUE(stub_->ListMeshes(&ctx, {}, &list).ok());
    int regions = 0;
    for (const v1::Mesh& m : list.meshes()) {
      if (m.name() == "body") regions += m.parent() == "spot" && m.parent_vertices() == 2930u;
      if (m.name() == "spot") {
        EXPECT_TRUE(m.parent().empty());
      }
    }
    EXPECT_EQ(regions, 1);
  }
  // Queried as any mesh, in its own vertex ids.
  const uint32_t n = region.diagnostics().vertices();
  auto distance = [&](uint32_t a, uint32_t b, double* d) {
    grpc::ClientContext ctx;
    v1::DistanceRequest req;
    req.mutable_graph()->set_mesh("body");  // at the default epsilon: started by the query
    *req.add_pairs()->mutable_from() = Vertex(a);
    *req.mutable_pairs(0)->mutable_to() = Vertex(b);
    v1::DistanceResponse resp;
    grpc::Status status = stub_->Distance(&ctx, req, &resp);
    if (status.ok() && resp.results_size() == 1) *d = resp.results(0).distance();
    return status;
  };
  double d = 0;
  s = distance(0, n - 1, &d);
  ASSERT_TRUE(s.ok()) << s.error_message();
  EXPECT_TRUE(std::isfinite(d) && d > 0) << d;
  EXPECT_EQ(distance(0, n, &d).error_code(), grpc::StatusCode::OUT_OF_RANGE);
  // Its parent stays while it is registered.
  {
    grpc::ClientContext ctx;
    v1::UnloadMeshRequest req;
    req.set_name("spot");
    v1::UnloadMeshResponse resp;
    s = stub_->UnloadMesh(&ctx, req, &resp);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
    EXPECT_THAT(s.error_message(), HasSubstr("'body'"));
  }
  // Mistakes, named.
  v1::Mesh bad;
  s = register_region("x", "nosuch", kept, {}, &bad);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::NOT_FOUND);
  s = register_region("x", "spot", {0, 5000}, {}, &bad);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::OUT_OF_RANGE);
  EXPECT_THAT(s.error_message(), HasSubstr("vertex id 5000"));
  s = register_region("x", "spot", {}, {}, &bad);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  s = register_region("x", "spot", {0, 1, 2}, {0}, &bad);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  s = register_region("x", "body", {0, 1, 2}, {}, &bad);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  std::vector<uint32_t> every_face((*spot)->mesh->num_faces());
  std::iota(every_face.begin(), every_face.end(), 0u);
  s = register_region("body", "spot", {}, every_face, &bad);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::ALREADY_EXISTS);
}

// A region recorded in a catalog is cut again from its parent by the next
// daemon, the same mesh (fingerprint), whichever order the names sort in.
TEST_F(ServiceTest, ARecordedRegionIsRestoredAfterItsParent) {
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / absl::StrCat("service_region_test.", getpid());
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  Catalog catalog(dir.string());
  auto hooks = [](MeshRegistry* registry) {
    return CatalogSync::Hooks{
        .restore_mesh =
            [registry](const CatalogMesh& m) {
              if (!m.parent.empty()) {
                return registry
                    ->RegisterRegion(m.name, m.parent,
                                     m.region_faces ? RegionMask::kFaces : RegionMask::kVertices,
                                     m.region_ids, m.fingerprint)
                    .status();
              }
              return registry->RegisterPath(m.name, m.source).status();
            },
        .drop_mesh = [registry](const std::string& name) { registry->Remove(name).IgnoreError(); },
        .request_graph = [](const std::string&, const DggParams&, double) {},
        .cancel_graph = [](const std::string&, const DggParams&, double) {}};
  };
  CatalogSync sync(&catalog, hooks(registry_.get()));
  service_->UseCatalog(&sync);
  {
    grpc::ClientContext ctx;
    v1::RegisterMeshRequest req;
    req.set_name("zspot");  // sorts after its region
    req.set_path("spot.obj");
    v1::Mesh mesh;
    ASSERT_TRUE(stub_->RegisterMesh(&ctx, req, &mesh).ok());
  }
  auto spot = registry_->Get("zspot");
  ASSERT_TRUE(spot.ok());
  grpc::ClientContext ctx;
  v1::RegisterRegionRequest req;
  req.set_name("body");
  req.set_parent("zspot");
  for (uint32_t v : SpotWithoutBand(*(*spot)->mesh)) req.add_vertex_ids(v);
  v1::Mesh region;
  grpc::Status s = stub_->RegisterRegion(&ctx, req, &region);
  ASSERT_TRUE(s.ok()) << s.error_message();
  // A region only the catalog knows (another replica's) keeps its parent too.
  ASSERT_TRUE(registry_->Remove("body").ok());
  {
    grpc::ClientContext unload_ctx;
    v1::UnloadMeshRequest unload;
    unload.set_name("zspot");
    v1::UnloadMeshResponse resp;
    s = stub_->UnloadMesh(&unload_ctx, unload, &resp);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
    EXPECT_THAT(s.error_message(), HasSubstr("'body'"));
    EXPECT_TRUE(registry_->Get("zspot").ok());
  }
  service_->UseCatalog(nullptr);

  auto state = catalog.Read();
  ASSERT_TRUE(state.ok()) << state.status();
  const CatalogMesh* recorded = state->FindMesh("body");
  ASSERT_NE(recorded, nullptr);
  EXPECT_EQ(recorded->parent, "zspot");
  EXPECT_EQ(recorded->region_ids.size(), size_t(req.vertex_ids_size()));
  MeshRegistry restarted(std::string(GEODESIC_SOURCE_DIR) + "/data");
  CatalogSync follower(&catalog, hooks(&restarted));
  ASSERT_TRUE(follower.Reconcile().ok());
  auto restored = restarted.Get("body");
  ASSERT_TRUE(restored.ok()) << restored.status();
  EXPECT_EQ(absl::StrFormat("%016x", (*restored)->fingerprint), region.fingerprint());
  EXPECT_EQ((*restored)->parent, "zspot");
  std::filesystem::remove_all(dir);
}

// A registration and an unload of one name, raced again and again with a
// catalog: whichever goes last, the registry and the catalog agree, so a
// client told "registered" is never answered "not found" (nor, after a
// restart, does an unloaded mesh come back).
TEST_F(ServiceTest, RaceOfRegisterAndUnloadLeavesRegistryAndCatalogAgreeing) {
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / absl::StrCat("service_test.", getpid());
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  Catalog catalog(dir.string());
  CatalogSync sync(
      &catalog,
      {.restore_mesh =
           [&](const CatalogMesh& m) { return registry_->RegisterPath(m.name, m.source).status(); },
       .drop_mesh = [&](const std::string& name) { registry_->Remove(name).IgnoreError(); },
       .request_graph = [](const std::string&, const DggParams&, double) {},
       .cancel_graph = [](const std::string&, const DggParams&, double) {}});
  service_->UseCatalog(&sync);
  auto register_raced = [&] {
    grpc::ClientContext ctx;
    v1::RegisterMeshRequest req;
    req.set_name("raced");
    req.set_path("spot.obj");
    v1::Mesh mesh;
    stub_->RegisterMesh(&ctx, req, &mesh);
  };
  auto unload_raced = [&] {
    grpc::ClientContext ctx;
    v1::UnloadMeshRequest req;
    req.set_name("raced");
    v1::UnloadMeshResponse resp;
    stub_->UnloadMesh(&ctx, req, &resp);
  };
  // The unload starts later and later in the registration, so that some
  // round lands in its last step, between loading and recording.
  const auto begin = std::chrono::steady_clock::now();
  register_raced();
  const auto registration = std::chrono::steady_clock::now() - begin;
  constexpr int kRounds = 100;
  for (int round = 0; round < kRounds; ++round) {
    unload_raced();
    std::thread registrar(register_raced);
    std::this_thread::sleep_for(registration * 1.5 * round / kRounds);
    unload_raced();
    registrar.join();
    auto state = catalog.Read();
    ASSERT_TRUE(state.ok()) << state.status();
    ASSERT_EQ(registry_->Get("raced").ok(), state->FindMesh("raced") != nullptr)
        << "round " << round;
  }
  service_->UseCatalog(nullptr);
  std::filesystem::remove_all(dir);
}

// The exposition parsed line by line: every series has HELP and TYPE, and
// counters (monotonic) are typed counter and end in _total.
TEST(MetricsTest, CountersAndGaugesAreTypedAsPrometheusExpects) {
  Metrics metrics;
  uint64_t hits = 5;
  metrics.AddCounter("geodesicd_cache_hits_total", "Hits.", [&] { return double(hits); });
  metrics.AddGauge("geodesicd_graph_mapped_bytes", "Mapped.", [] { return 1024.0; });
  metrics.Record("Distance", "OK", 0.003);
  metrics.Record("Distance", "OK", 0.3);
  metrics.Record("Distance", "NOT_FOUND", 0.001);
  const std::string page = metrics.Render();
  std::map<std::string, std::string> types;
  std::map<std::string, double> values;
  std::istringstream in(page);
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("# TYPE ", 0) == 0) {
      std::istringstream f(line.substr(7));
      std::string name, type;
      f >> name >> type;
      types[name] = type;
    } else if (!line.empty() && line[0] != '#') {
      const size_t space = line.rfind(' ');
      values[line.substr(0, space)] = std::stod(line.substr(space + 1));
    }
  }
  for (const auto& [name, type] : types) {
    EXPECT_THAT(page, HasSubstr("# HELP " + name + " ")) << name;
    if (type == "counter") {
      EXPECT_TRUE(name.ends_with("_total")) << name;
    }
  }
  EXPECT_EQ(types["geodesicd_cache_hits_total"], "counter");
  EXPECT_EQ(types["geodesicd_requests_total"], "counter");
  EXPECT_EQ(types["geodesicd_graph_mapped_bytes"], "gauge");
  EXPECT_EQ(types["geodesicd_request_seconds"], "histogram");
  EXPECT_EQ(values["geodesicd_cache_hits_total"], 5);
  EXPECT_EQ(values["geodesicd_requests_total{method=\"Distance\",code=\"OK\"}"], 2);
  EXPECT_EQ(values["geodesicd_requests_total{method=\"Distance\",code=\"NOT_FOUND\"}"], 1);
  EXPECT_EQ(values["geodesicd_request_seconds_bucket{method=\"Distance\",le=\"0.005\"}"], 2);
  EXPECT_EQ(values["geodesicd_request_seconds_count{method=\"Distance\"}"], 3);
  hits = 6;  // read when rendered
  EXPECT_THAT(metrics.Render(), HasSubstr("geodesicd_cache_hits_total 6\n"));
}

TEST(MeshRegistryTest, NamesPathsAndContentsAreChecked) {
  MeshRegistry registry(std::string(GEODESIC_SOURCE_DIR) + "/data");
  auto spot = registry.RegisterPath("spot", "spot.obj");
  ASSERT_TRUE(spot.ok()) << spot.status();
  EXPECT_EQ((*spot)->mesh->num_vertices(), 2930u);
  // The same contents again is the same mesh; a bad name or a path outside
  // the root is refused by name.
  auto again = registry.RegisterPath("spot", "spot.obj");
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->get(), spot->get());
  EXPECT_EQ(registry.RegisterPath("bad name", "spot.obj").status().code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(registry.RegisterPath("evil", "../../etc/passwd").status().code(),
            absl::StatusCode::kPermissionDenied);
  EXPECT_EQ(registry.RegisterPath("none", "no-such.obj").status().code(),
            absl::StatusCode::kNotFound);
  // Other contents under a taken name: ALREADY_EXISTS, the old mesh kept.
  const std::string tiny = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
  EXPECT_EQ(registry.RegisterBytes("spot", "obj", tiny).status().code(),
            absl::StatusCode::kAlreadyExists);
  EXPECT_EQ((*registry.Get("spot"))->mesh->num_vertices(), 2930u);
  auto uploaded = registry.RegisterBytes("tiny", "obj", tiny);
  ASSERT_TRUE(uploaded.ok()) << uploaded.status();
  EXPECT_EQ((*uploaded)->source, "upload");
  EXPECT_EQ(registry.List().size(), 2u);
  EXPECT_TRUE(registry.Remove("tiny").ok());
  EXPECT_EQ(registry.Remove("tiny").code(), absl::StatusCode::kNotFound);
}

}  // namespace
}  // namespace geodesic::server
