// geodesicd serve --config: what a deployment declares, and the errors that
// point at the line to fix.
#include "server/app/config_file.h"

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

// max_error instead of eps declares the certified graph of that bound.
TEST(ConfigFileTest, ParsesCertifiedGraphs) {
  auto config = ParseServeConfig(R"(
meshes:
  - name: kitten
    path: scans/kitten.off
graphs:
  - mesh: kitten
    max_error: 0.01
  - mesh: kitten
    max_error: 1e-3
    pseudo_vertices: true
  - mesh: kitten
    eps: 1e-3
)",
                                 "deploy.yaml");
  ASSERT_TRUE(config.ok()) << config.status();
  ASSERT_EQ(config->graphs.size(), 3u);
  EXPECT_EQ(config->graphs[0].max_error, 0.01);
  EXPECT_EQ(config->graphs[0].epsilon, 0);
  EXPECT_FALSE(config->graphs[0].pseudo_vertices);
  EXPECT_EQ(config->graphs[1].max_error, 1e-3);
  EXPECT_TRUE(config->graphs[1].pseudo_vertices);
  EXPECT_EQ(config->graphs[2].max_error, 0);  // a plain graph
  EXPECT_EQ(config->graphs[2].epsilon, 1e-3);
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
      {"meshes:\n  - {name: a, path: a.obj}\ngraphs:\n  - {mesh: a, max_error: 0}\n",
       "deploy.yaml:4:26: graphs[0].max_error must be in [1e-5, 0.5], not 0"},
      {"meshes:\n  - {name: a, path: a.obj}\ngraphs:\n  - {mesh: a, max_error: -0.01}\n",
       "graphs[0].max_error must be in [1e-5, 0.5], not -0.01"},
      {"meshes:\n  - {name: a, path: a.obj}\ngraphs:\n  - {mesh: a, max_error: .inf}\n",
       "graphs[0].max_error must be in [1e-5, 0.5], not inf"},
      {"meshes:\n  - {name: a, path: a.obj}\ngraphs:\n  - {mesh: a, max_error: .nan}\n",
       "graphs[0].max_error must be in [1e-5, 0.5], not nan"},
      {"meshes:\n  - {name: a, path: a.obj}\ngraphs:\n  - {mesh: a, max_error: 0.9}\n",
       "graphs[0].max_error must be in [1e-5, 0.5], not 0.9"},
      {"meshes:\n  - {name: a, path: a.obj}\ngraphs:\n  - {mesh: a, max_error: tight}\n",
       "graphs[0].max_error must be a number, not 'tight'"},
      {"meshes:\n  - {name: a, path: a.obj}\ngraphs:\n  - {mesh: a, eps: 1e-3, max_error: 0.01}\n",
       "deploy.yaml:4:20: graphs[0] gives both 'eps' and 'max_error'"},
      {"meshes:\n  - {name: a, path: a.obj}\ngraphs:\n  - {mesh: a, pseudo_vertices: true}\n",
       "deploy.yaml:4:5: graphs[0] needs 'eps' (or 'max_error', for a certified graph)"},
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
