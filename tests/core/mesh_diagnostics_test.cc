// MeshDiagnostics::ToJson: the keys, their order and their JSON types are a
// contract (`geodesicd info --json`, the gRPC API's diagnostics JSON and
// scripts read them), so every key is pinned here with the type it has and
// the struct field it carries.
#include "core/mesh/mesh_diagnostics.h"

#include <cmath>
#include <string>
#include <vector>

#include "core/mesh/mesh_io.h"
#include "nlohmann/json.hpp"
#include "tests/core/test_util.h"

namespace geodesic {
namespace {

using Json = nlohmann::ordered_json;
using testing::SourcePath;

enum class Type { kString, kUnsigned, kInteger, kFloat, kBool };

struct Key {
  const char* name;
  Type type;
};

// Every key of ToJson, in the order it prints them.
const std::vector<Key> kKeys = {
    {"path", Type::kString},
    {"format", Type::kString},
    {"vertices", Type::kUnsigned},
    {"faces", Type::kUnsigned},
    {"edges", Type::kUnsigned},
    {"polygons_triangulated", Type::kUnsigned},
    {"components", Type::kUnsigned},
    {"boundary_loops", Type::kUnsigned},
    {"genus", Type::kInteger},
    {"isolated_vertices", Type::kUnsigned},
    {"duplicate_vertices", Type::kUnsigned},
    {"zero_area_faces", Type::kUnsigned},
    {"near_degenerate_faces", Type::kUnsigned},
    {"non_manifold_edges", Type::kUnsigned},
    {"non_manifold_vertices", Type::kUnsigned},
    {"faces_refused", Type::kUnsigned},
    {"bbox_diagonal", Type::kFloat},
    {"mean_edge_length", Type::kFloat},
    {"min_edge_length", Type::kFloat},
    {"anisotropy_mean", Type::kFloat},
    {"anisotropy_p95", Type::kFloat},
    {"anisotropy_max", Type::kFloat},
    {"saddle_vertices", Type::kUnsigned},
    {"boundary_vertices", Type::kUnsigned},
    {"manifold", Type::kBool},
    {"usable", Type::kBool},
    {"mesh_error", Type::kString},
    {"load_seconds", Type::kFloat},
};

bool HasType(const Json& v, Type t) {
  switch (t) {
    case Type::kString:
      return v.is_string();
    case Type::kUnsigned:
      return v.is_number_integer() && (v.is_number_unsigned() || v.get<int64_t>() >= 0);
    case Type::kInteger:
      return v.is_number_integer();
    case Type::kFloat:
      // A whole-number measure too: 0.0, not 0 (the format strings ToJson
      // once used spelled such a double as an integer).
      return v.is_number_float();
    case Type::kBool:
      return v.is_boolean();
  }
  return false;
}

Json Parse(const MeshDiagnostics& d) {
  const std::string text = d.ToJson();
  Json j = Json::parse(text, nullptr, /*allow_exceptions=*/false);
  EXPECT_FALSE(j.is_discarded()) << "not JSON: " << text;
  return j;
}

void ExpectKeysAndTypes(const Json& j) {
  ASSERT_TRUE(j.is_object()) << j;
  std::vector<std::string> names, want;
  for (const auto& [name, value] : j.items()) names.push_back(name);
  for (const Key& k : kKeys) want.push_back(k.name);
  EXPECT_EQ(names, want);
  for (const Key& k : kKeys) {
    if (!j.contains(k.name)) continue;
    EXPECT_TRUE(HasType(j[k.name], k.type)) << k.name << " is " << j[k.name].type_name();
  }
}

// Each key carries its field (doubles exactly: they are printed to read
// back as the same value), load_seconds to the microsecond.
void ExpectValues(const Json& j, const MeshDiagnostics& d) {
  EXPECT_EQ(j["path"], d.path);
  EXPECT_EQ(j["format"], d.format);
  EXPECT_EQ(j["vertices"].get<uint64_t>(), d.vertices);
  EXPECT_EQ(j["faces"].get<uint64_t>(), d.faces);
  EXPECT_EQ(j["edges"].get<uint64_t>(), d.edges);
  EXPECT_EQ(j["polygons_triangulated"].get<uint64_t>(), d.polygons_triangulated);
  EXPECT_EQ(j["components"].get<uint64_t>(), d.components);
  EXPECT_EQ(j["boundary_loops"].get<uint64_t>(), d.boundary_loops);
  EXPECT_EQ(j["genus"].get<int64_t>(), d.genus);
  EXPECT_EQ(j["isolated_vertices"].get<uint64_t>(), d.isolated_vertices);
  EXPECT_EQ(j["duplicate_vertices"].get<uint64_t>(), d.duplicate_vertices);
  EXPECT_EQ(j["zero_area_faces"].get<uint64_t>(), d.zero_area_faces);
  EXPECT_EQ(j["near_degenerate_faces"].get<uint64_t>(), d.near_degenerate_faces);
  EXPECT_EQ(j["non_manifold_edges"].get<uint64_t>(), d.non_manifold_edges);
  EXPECT_EQ(j["non_manifold_vertices"].get<uint64_t>(), d.non_manifold_vertices);
  EXPECT_EQ(j["faces_refused"].get<uint64_t>(), d.faces_refused);
  EXPECT_EQ(j["bbox_diagonal"].get<double>(), d.bbox_diagonal);
  EXPECT_EQ(j["mean_edge_length"].get<double>(), d.mean_edge_length);
  EXPECT_EQ(j["min_edge_length"].get<double>(), d.min_edge_length);
  EXPECT_EQ(j["anisotropy_mean"].get<double>(), d.anisotropy_mean);
  EXPECT_EQ(j["anisotropy_p95"].get<double>(), d.anisotropy_p95);
  EXPECT_EQ(j["anisotropy_max"].get<double>(), d.anisotropy_max);
  EXPECT_EQ(j["saddle_vertices"].get<uint64_t>(), d.saddle_vertices);
  EXPECT_EQ(j["boundary_vertices"].get<uint64_t>(), d.boundary_vertices);
  EXPECT_EQ(j["manifold"].get<bool>(), d.manifold);
  EXPECT_EQ(j["usable"].get<bool>(), d.mesh_error.empty());
  EXPECT_EQ(j["mesh_error"], d.mesh_error);
  EXPECT_NEAR(j["load_seconds"].get<double>(), d.load_seconds, 0.5e-6);
}

TEST(MeshDiagnosticsJsonTest, TheBundledMeshHasEveryKeyWithItsTypeAndValue) {
  MeshDiagnostics d;
  ASSERT_OK(LoadMesh(SourcePath("data/spot.obj"), {}, &d));
  const Json j = Parse(d);
  ExpectKeysAndTypes(j);
  ExpectValues(j, d);
  EXPECT_EQ(j["vertices"], 2930);
  EXPECT_EQ(j["format"], "obj");
  EXPECT_EQ(j["usable"], true);
  EXPECT_EQ(j["mesh_error"], "");
  // The measures of a real mesh are not whole numbers: they read as floats.
  for (const char* key : {"bbox_diagonal", "mean_edge_length", "min_edge_length", "anisotropy_mean",
                          "anisotropy_p95", "anisotropy_max", "load_seconds"}) {
    EXPECT_TRUE(j[key].is_number_float()) << key << " is " << j[key];
  }
}

TEST(MeshDiagnosticsJsonTest, StringsAreEscapedAndAnErrorMakesTheMeshUnusable) {
  MeshDiagnostics d;
  d.path = "dir/we\"ird\\name\n\t\x01.obj";
  d.format = "obj";
  d.vertices = 18446744073709551615u;  // the largest uint64 survives
  d.genus = -3;
  d.bbox_diagonal = 0.1;
  d.anisotropy_max = 1e300;
  d.min_edge_length = 5e-324;
  d.load_seconds = 1.25;
  d.mesh_error = "spot.obj: vertex 7 is \"non-manifold\"";
  const Json j = Parse(d);
  ExpectKeysAndTypes(j);
  ExpectValues(j, d);
  EXPECT_EQ(j["usable"], false);
  EXPECT_EQ(j["genus"], -3);
  EXPECT_EQ(j["load_seconds"].get<double>(), 1.25);
}

TEST(MeshDiagnosticsJsonTest, WholeNumberMeasuresAreStillFloats) {
  MeshDiagnostics d;  // an empty file's: every measure 0
  d.bbox_diagonal = 2;
  const Json j = Parse(d);
  ExpectKeysAndTypes(j);
  ExpectValues(j, d);
  EXPECT_THAT(d.ToJson(), ::testing::HasSubstr("\"bbox_diagonal\":2.0,"));
}

TEST(MeshDiagnosticsJsonTest, NonFiniteMeasuresAndBytesThatAreNotUtf8StillMakeJson) {
  MeshDiagnostics d;
  d.path = "caf\xe9.obj";  // Latin-1, not UTF-8
  d.anisotropy_max = INFINITY;
  d.anisotropy_mean = NAN;
  const Json j = Parse(d);
  ASSERT_TRUE(j.is_object());
  EXPECT_EQ(j["path"], "caf\ufffd.obj");
  EXPECT_TRUE(j["anisotropy_max"].is_null());
  EXPECT_TRUE(j["anisotropy_mean"].is_null());
  EXPECT_TRUE(j["anisotropy_p95"].is_number_float());
}

}  // namespace
}  // namespace geodesic
