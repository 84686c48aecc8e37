// One JSON view per message (server/api/json_views.h): every proto field
// has its key, and the CLI's and the gateway's views are the same one.
#include "server/api/json_views.h"

#include <set>
#include <string>

#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "server/gateway/json_answers.h"

namespace geodesic::server {
namespace {

using nlohmann::json;
using nlohmann::ordered_json;

template <typename Json>
std::set<std::string> Keys(const Json& object) {
  std::set<std::string> keys;
  for (auto it = object.begin(); it != object.end(); ++it) keys.insert(it.key());
  return keys;
}

std::set<std::string> FieldNames(const google::protobuf::Descriptor* message) {
  std::set<std::string> names;
  for (int i = 0; i < message->field_count(); ++i) names.insert(message->field(i)->name());
  return names;
}

v1::Graph ReadyGraph() {
  v1::Graph g;
  g.set_mesh("spot");
  g.set_epsilon(1e-3);
  g.set_state(v1::GRAPH_STATE_READY);
  g.set_edges(12345);
  g.mutable_certificate()->set_sources(4);
  return g;
}

TEST(JsonViewsTest, GraphHasAKeyForEveryField) {
  const std::set<std::string> keys = Keys(GraphJson<json>(ReadyGraph()));
  ASSERT_FALSE(keys.empty());
  for (const std::string& field : FieldNames(v1::Graph::descriptor())) {
    EXPECT_TRUE(keys.count(field)) << "GraphJson has no key for Graph." << field;
  }
}

TEST(JsonViewsTest, MeshHasAKeyForEveryField) {
  v1::Mesh m;
  m.set_name("part");
  m.set_parent("spot");
  m.add_vertex_copies()->set_copy(9);
  m.mutable_diagnostics()->set_vertices(3);
  const std::set<std::string> keys = Keys(MeshJson<json>(m));
  ASSERT_FALSE(keys.empty());
  for (const std::string& field : FieldNames(v1::Mesh::descriptor())) {
    EXPECT_TRUE(keys.count(field)) << "MeshJson has no key for Mesh." << field;
  }
  EXPECT_EQ(MeshJson<json>(m)["vertex_copies"][0]["copy"], 9);
}

TEST(JsonViewsTest, CliAndGatewayShareTheKeys) {
  const v1::Graph g = ReadyGraph();
  const ordered_json cli = GraphJson<ordered_json>(g);
  const json http = gateway::GraphJson(g);
  std::set<std::string> http_keys = Keys(http);
  // HTTP v1's spelling of epsilon, kept beside the shared key.
  EXPECT_EQ(http_keys.erase("eps"), 1u);
  EXPECT_EQ(Keys(cli), http_keys);
  EXPECT_EQ(cli["state"], "ready");
  EXPECT_EQ(http["state"], "READY");
  EXPECT_EQ(http["eps"], cli["epsilon"]);
  EXPECT_EQ(cli["edges"], 12345);
  EXPECT_EQ(cli["certificate"]["sources"], 4);

  v1::Mesh m;
  m.set_name("spot");
  EXPECT_EQ(Keys(MeshJson<ordered_json>(m)), Keys(gateway::MeshJson(m)));
  // A whole mesh has no parent's keys; a region has them.
  EXPECT_FALSE(MeshJson<json>(m).contains("parent"));
  m.set_parent("cow");
  EXPECT_EQ(MeshJson<json>(m)["parent"], "cow");
}

TEST(JsonViewsTest, ACertificateIsNullUntilThereIsOne) {
  v1::Graph g = ReadyGraph();
  g.clear_certificate();
  EXPECT_TRUE(GraphJson<json>(g)["certificate"].is_null());
}

TEST(JsonViewsTest, UnknownStatesHaveAName) {
  EXPECT_STREQ(StateName(static_cast<v1::GraphState>(99)), "unknown");
  EXPECT_STREQ(StateName(v1::GRAPH_STATE_CANCELLED), "cancelled");
}

}  // namespace
}  // namespace geodesic::server
