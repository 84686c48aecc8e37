#include "server/app/config_file.h"

#include <cmath>
#include <fstream>
#include <set>
#include <sstream>

#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "server/graphs/graph_key.h"
#include "yaml-cpp/yaml.h"

namespace geodesic::server {
namespace {

// A problem at a node, reported as "path:line:column: what". Thrown and
// caught inside ParseServeConfig only.
struct ConfigError {
  std::string what;
  YAML::Mark mark;
};

void Expect(bool ok, const YAML::Node& node, const std::string& what) {
  if (!ok) throw ConfigError{what, node.Mark()};
}

void OnlyKeys(const YAML::Node& map, const std::set<std::string>& allowed,
              const std::string& where) {
  Expect(map.IsMap(), map, where + " must be a mapping");
  for (const auto& entry : map) {
    const std::string key = entry.first.as<std::string>();
    Expect(allowed.contains(key), entry.first,
           absl::StrFormat("unknown key '%s' in %s (expected %s)", key, where,
                           absl::StrJoin(allowed, ", ")));
  }
}

template <typename T>
T Scalar(const YAML::Node& map, const std::string& key, const std::string& where,
         const char* type) {
  const YAML::Node node = map[key];
  Expect(node.IsDefined() && !node.IsNull(), map, absl::StrFormat("%s needs '%s'", where, key));
  Expect(node.IsScalar(), node, absl::StrFormat("%s.%s must be %s", where, key, type));
  try {
    return node.as<T>();
  } catch (const YAML::Exception&) {
    throw ConfigError{
        absl::StrFormat("%s.%s must be %s, not '%s'", where, key, type, node.Scalar()),
        node.Mark()};
  }
}

template <typename T>
T Optional(const YAML::Node& map, const std::string& key, const std::string& where,
           const char* type, T fallback) {
  return map[key].IsDefined() ? Scalar<T>(map, key, where, type) : fallback;
}

ServeConfig Parse(const YAML::Node& root, const std::string& path) {
  ServeConfig config;
  if (root.IsNull()) return config;  // an empty file declares nothing
  OnlyKeys(root, {"meshes", "graphs", "flags"}, "the file");
  if (const YAML::Node flags = root["flags"]; flags.IsDefined() && !flags.IsNull()) {
    Expect(flags.IsMap(), flags, "flags must be a mapping of serve flags to values");
    for (const auto& entry : flags) {
      const std::string name = entry.first.as<std::string>();
      Expect(!name.empty() &&
                 name.find_first_not_of("abcdefghijklmnopqrstuvwxyz0123456789-") ==
                     std::string::npos &&
                 !name.starts_with("-"),
             entry.first,
             absl::StrFormat("flags: '%s' is not a flag's name (write it without dashes, as "
                             "memory-limit)",
                             name));
      Expect(name != "config", entry.first, "flags: a config file cannot name another");
      Expect(entry.second.IsScalar(), entry.second,
             absl::StrFormat("flags.%s must be one value", name));
      const YAML::Mark mark = entry.first.Mark();
      config.flags.push_back({name, entry.second.Scalar(),
                              absl::StrFormat("%s:%d:%d", path, mark.line + 1, mark.column + 1)});
    }
  }
  std::set<std::string> names;
  if (const YAML::Node meshes = root["meshes"]; meshes.IsDefined() && !meshes.IsNull()) {
    Expect(meshes.IsSequence(), meshes, "meshes must be a list");
    for (size_t i = 0; i < meshes.size(); ++i) {
      const std::string where = absl::StrFormat("meshes[%u]", i);
      OnlyKeys(meshes[i], {"name", "path", "repair_non_manifold"}, where);
      DeclaredMesh m;
      m.name = Scalar<std::string>(meshes[i], "name", where, "a string");
      m.path = Scalar<std::string>(meshes[i], "path", where, "a string");
      m.repair_non_manifold =
          Optional<bool>(meshes[i], "repair_non_manifold", where, "true or false", false);
      Expect(names.insert(m.name).second, meshes[i]["name"],
             absl::StrFormat("mesh '%s' is declared twice", m.name));
      config.meshes.push_back(std::move(m));
    }
  }
  if (const YAML::Node graphs = root["graphs"]; graphs.IsDefined() && !graphs.IsNull()) {
    Expect(graphs.IsSequence(), graphs, "graphs must be a list");
    for (size_t i = 0; i < graphs.size(); ++i) {
      const std::string where = absl::StrFormat("graphs[%u]", i);
      OnlyKeys(graphs[i], {"mesh", "eps", "max_error", "pseudo_vertices"}, where);
      DeclaredGraph g;
      g.mesh = Scalar<std::string>(graphs[i], "mesh", where, "a string");
      Expect(names.contains(g.mesh), graphs[i]["mesh"],
             absl::StrFormat("%s names mesh '%s', which the file does not declare", where, g.mesh));
      if (graphs[i]["max_error"].IsDefined()) {
        // A certified graph: its build chooses the epsilon, so an `eps`
        // beside the bound would be ignored, and is refused instead.
        Expect(!graphs[i]["eps"].IsDefined(), graphs[i]["eps"],
               absl::StrFormat("%s gives both 'eps' and 'max_error': a certified graph's "
                               "epsilon is chosen by its build, give one of them",
                               where));
        g.max_error = Scalar<double>(graphs[i], "max_error", where, "a number");
        Expect(IsCertifiableBound(g.max_error), graphs[i]["max_error"],
               absl::StrFormat("%s.max_error must be in %s, not %g", where, kMaxErrorRange,
                               g.max_error));
      } else {
        Expect(graphs[i]["eps"].IsDefined(), graphs[i],
               absl::StrFormat("%s needs 'eps' (or 'max_error', for a certified graph)", where));
        g.epsilon = Scalar<double>(graphs[i], "eps", where, "a number");
        Expect(g.epsilon > 0 && g.epsilon < 1, graphs[i]["eps"],
               absl::StrFormat("%s.eps must be in (0, 1), not %g", where, g.epsilon));
      }
      g.pseudo_vertices =
          Optional<bool>(graphs[i], "pseudo_vertices", where, "true or false", false);
      config.graphs.push_back(std::move(g));
    }
  }
  return config;
}

}  // namespace

absl::StatusOr<ServeConfig> ParseServeConfig(const std::string& text, const std::string& path) {
  try {
    return Parse(YAML::Load(text), path);
  } catch (const ConfigError& e) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s:%d:%d: %s", path, e.mark.line + 1, e.mark.column + 1, e.what));
  } catch (const YAML::Exception& e) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s:%d:%d: %s", path, e.mark.line + 1, e.mark.column + 1, e.msg));
  }
}

absl::StatusOr<ServeConfig> LoadServeConfig(const std::string& path) {
  std::ifstream in(path);
  if (!in) return absl::NotFoundError(absl::StrFormat("cannot read config file %s", path));
  std::stringstream text;
  text << in.rdbuf();
  return ParseServeConfig(text.str(), path);
}

}  // namespace geodesic::server
