// geodesicd serve --config: what a deployment declares, and the errors that
// point at the line to fix.
#include "server/config_file.h"

#include "gmock/gmock.h"
#include "gtest/gtest.h"

namespace geodesic::server {
namespace {

using ::testing::HasSubstr;

TEST(ConfigFileTest, ParsesMeshesAndGraphsWithDefaults) {
  auto config = ParseServeConfig(R"(
meshes:
  - name: kitten
    path: scans/kitten.off
  - name: ogre
    path: /data/ogre.obj
    repair_non_manifold: true
graphs:
  - mesh: kitten
    eps: 1e-3
  - mesh: ogre
    eps: 0.01
    pseudo_vertices: true
)",
                                 "deploy.yaml");
  ASSERT_TRUE(config.ok()) << config.status();
  ASSERT_EQ(config->meshes.size(), 2u);
  EXPECT_EQ(config->meshes[0].name, "kitten");
  EXPECT_EQ(config->meshes[0].path, "scans/kitten.off");
  EXPECT_FALSE(config->meshes[0].repair_non_manifold);
  EXPECT_TRUE(config->meshes[1].repair_non_manifold);
  ASSERT_EQ(config->graphs.size(), 2u);
  EXPECT_EQ(config->graphs[0].mesh, "kitten");
  EXPECT_EQ(config->graphs[0].epsilon, 1e-3);
  EXPECT_FALSE(config->graphs[0].pseudo_vertices);
  EXPECT_EQ(config->graphs[1].epsilon, 0.01);
  EXPECT_TRUE(config->graphs[1].pseudo_vertices);
}

TEST(ConfigFileTest, AnEmptyFileDeclaresNothing) {
  for (const char* text : {"", "# nothing yet\n", "meshes:\ngraphs:\n"}) {
    auto config = ParseServeConfig(text, "empty.yaml");
    ASSERT_TRUE(config.ok()) << config.status();
    EXPECT_TRUE(config->meshes.empty());
    EXPECT_TRUE(config->graphs.empty());
  }
}

TEST(ConfigFileTest, ErrorsNameTheFileLineAndKey) {
  struct Case {
    const char* text;
    const char* says;
  };
  const Case cases[] = {
      {"meshes:\n  - name: a\n    path: a.obj\ngraphs:\n  - mesh: a\n    eps: 1e-3\n"
       "    pseudo_vertice: true\n",
       "deploy.yaml:7:5: unknown key 'pseudo_vertice' in graphs[0]"},
      {"meshes:\n  - name: a\n", "deploy.yaml:2:5: meshes[0] needs 'path'"},
      {"graphs:\n  - mesh: b\n    eps: 1e-3\n",
       "deploy.yaml:2:11: graphs[0] names mesh 'b', which the file does not declare"},
      {"meshes:\n  - {name: a, path: a.obj}\ngraphs:\n  - {mesh: a, eps: 2}\n",
       "graphs[0].eps must be in (0, 1), not 2"},
      {"meshes:\n  - {name: a, path: a.obj}\ngraphs:\n  - {mesh: a, eps: small}\n",
       "graphs[0].eps must be a number, not 'small'"},
      {"meshes:\n  - {name: a, path: a.obj}\n  - {name: a, path: b.obj}\n",
       "deploy.yaml:3:12: mesh 'a' is declared twice"},
      {"meshes:\n  - {name: a, path: a.obj, repair_non_manifold: maybe}\n",
       "repair_non_manifold must be true or false"},
      {"meshes: {name: a}\n", "meshes must be a list"},
      {"mesh:\n  - {name: a, path: a.obj}\n", "unknown key 'mesh' in the file"},
      {"meshes: [\n", "deploy.yaml:"},  // not YAML at all
  };
  for (const Case& c : cases) {
    auto config = ParseServeConfig(c.text, "deploy.yaml");
    ASSERT_FALSE(config.ok()) << c.text;
    EXPECT_EQ(config.status().code(), absl::StatusCode::kInvalidArgument);
    EXPECT_THAT(std::string(config.status().message()), HasSubstr(c.says)) << c.text;
  }
  EXPECT_EQ(LoadServeConfig("/nonexistent/deploy.yaml").status().code(),
            absl::StatusCode::kNotFound);
}

}  // namespace
}  // namespace geodesic::server
