// server/web/openapi.json, the HTTP API's contract that clients read and
// generate code from, is written by hand; the gateway's route table is what
// answers. This holds one to the other both ways: every route (method, path,
// the body keys it takes) is documented as it is, and everything documented
// is a route, so that neither can drift from the other unnoticed.
#include <cctype>
#include <fstream>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "server/gateway/http_gateway.h"
#include "server/gateway/json_answers.h"

namespace geodesic::server {
namespace {

using OpenApi = nlohmann::json;

OpenApi ReadOpenApiDocument() {
  std::ifstream in(std::string(GEODESIC_SOURCE_DIR) + "/server/web/openapi.json");
  std::stringstream text;
  text << in.rdbuf();
  return OpenApi::parse(text.str(), nullptr, /*allow_exceptions=*/false);
}

// A "$ref": "#/components/..." stands for the object it names.
const OpenApi& Resolved(const OpenApi& doc, const OpenApi& node) {
  if (!node.is_object() || !node.contains("$ref")) return node;
  return doc.at(OpenApi::json_pointer(node["$ref"].get<std::string>().substr(1)));
}

// The table's "{}" segment is the mesh's name, {name} in the document.
std::string DocumentedPath(const std::string& pattern) {
  std::string path = pattern;
  for (size_t at = path.find("{}"); at != std::string::npos; at = path.find("{}", at)) {
    path.replace(at, 2, "{name}");
  }
  return path;
}

std::string Lower(std::string text) {
  for (char& c : text) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return text;
}

std::string Joined(const std::set<std::string>& keys) {
  std::string out;
  for (const std::string& key : keys) out += (out.empty() ? "" : ", ") + key;
  return "{" + out + "}";
}

// What a route's documentation gets wrong: its path parameter and the keys
// of its JSON body.
void CheckOperation(const OpenApi& doc, const GatewayRoute& route, const OpenApi& operation,
                    const OpenApi& path_item, std::vector<std::string>* problems) {
  const std::string where = route.method + " " + DocumentedPath(route.path);
  if (route.path.find("{}") != std::string::npos) {
    bool declared = false;
    for (const OpenApi* list : {&path_item, &operation}) {
      for (const OpenApi& p : list->value("parameters", OpenApi::array())) {
        const OpenApi& param = Resolved(doc, p);
        declared |= param.value("in", "") == "path" && param.value("name", "") == "name" &&
                    param.value("required", false);
      }
    }
    if (!declared) problems->push_back(where + ": no required path parameter 'name'");
  }
  const std::set<std::string> want(route.body_keys.begin(), route.body_keys.end());
  // value() answers a copy: each is held here, as Resolved may answer it.
  const OpenApi request_body = operation.value("requestBody", OpenApi::object());
  const OpenApi content = Resolved(doc, request_body).value("content", OpenApi::object());
  if (!content.contains("application/json")) {
    if (!want.empty()) {
      problems->push_back(where + ": takes a JSON body " + Joined(want) + ", documents none");
    }
    return;
  }
  const OpenApi schema_node = content["application/json"].value("schema", OpenApi::object());
  const OpenApi& schema = Resolved(doc, schema_node);
  const OpenApi properties = schema.value("properties", OpenApi::object());
  std::set<std::string> have;
  for (const auto& [key, value] : properties.items()) {
    have.insert(key);
  }
  if (want.empty()) {
    problems->push_back(where + ": takes no JSON body, documents " + Joined(have));
    return;
  }
  if (have != want) {
    problems->push_back(where + ": body keys " + Joined(want) + ", documented " + Joined(have));
  }
  // The gateway refuses a key it does not take (400), rather than ignore it.
  if (schema.value("additionalProperties", true) != false) {
    problems->push_back(where + ": body schema lacks \"additionalProperties\": false");
  }
}

TEST(OpenApiRoutesTest, DocumentMatchesTheRouteTableBothWays) {
  const std::vector<GatewayRoute> routes = HttpGateway::Routes();
  const OpenApi doc = ReadOpenApiDocument();
  ASSERT_FALSE(routes.empty());
  ASSERT_TRUE(doc.is_object()) << "server/web/openapi.json is not a JSON object";
  ASSERT_TRUE(doc.contains("paths") && doc["paths"].is_object() && !doc["paths"].empty())
      << "server/web/openapi.json documents no paths";
  const OpenApi& paths = doc["paths"];

  std::vector<std::string> problems;
  std::set<std::string> routed;  // "post /v1/meshes/{name}/distance"
  for (const GatewayRoute& route : routes) {
    const std::string path = DocumentedPath(route.path), method = Lower(route.method);
    routed.insert(method + " " + path);
    if (!paths.contains(path)) {
      problems.push_back(route.method + " " + path + ": path not in openapi.json");
    } else if (!paths[path].contains(method)) {
      problems.push_back(route.method + " " + path + ": method not in openapi.json");
    } else {
      CheckOperation(doc, route, paths[path][method], paths[path], &problems);
    }
  }
  const std::set<std::string> kMethods = {"get",     "put",  "post",  "delete",
                                          "options", "head", "patch", "trace"};
  for (const auto& [path, item] : paths.items()) {
    for (const auto& [method, operation] : item.items()) {
      if (kMethods.count(method) && !routed.count(method + " " + path)) {
        problems.push_back(method + " " + path + ": documented, but the gateway has no such route");
      }
    }
  }
  for (const std::string& problem : problems) ADD_FAILURE() << problem;
  EXPECT_TRUE(problems.empty()) << problems.size() << " differences";
}

// The answers' schemas name the keys the gateway's JSON views write
// (server/api/json_views.h), no more and no fewer.
TEST(OpenApiRoutesTest, MeshAndGraphSchemasMatchTheViews) {
  const OpenApi doc = ReadOpenApiDocument();
  ASSERT_TRUE(doc.is_object()) << "server/web/openapi.json is missing or not JSON";
  v1::Graph graph;
  graph.mutable_certificate()->set_sources(1);
  v1::Mesh mesh;  // a region: every key a mesh may have
  mesh.set_name("part");
  mesh.set_parent("spot");
  const std::vector<std::pair<std::string, OpenApi>> views = {{"Graph", gateway::GraphJson(graph)},
                                                              {"Mesh", gateway::MeshJson(mesh)}};
  for (const auto& [schema, view] : views) {
    std::set<std::string> documented, written;
    for (const auto& [key, value] : doc["components"]["schemas"][schema]["properties"].items()) {
      documented.insert(key);
    }
    for (const auto& [key, value] : view.items()) written.insert(key);
    ASSERT_FALSE(written.empty());
    EXPECT_EQ(documented, written) << schema << ": openapi.json documents " << Joined(documented)
                                   << ", the gateway writes " << Joined(written);
  }
}

}  // namespace
}  // namespace geodesic::server
