// cgal_peer: CGAL's geodesic solvers on the same mesh and source, for the
// benchmark's side-by-side tables: the heat method (plain and on the
// intrinsic Delaunay triangulation) and the exact Surface_mesh_shortest_path.
//
//   cgal_peer MESH VERTEX OUT_PREFIX
//
// Writes OUT_PREFIX.{heat,heat-idt,exact}.f64 (one float64 per vertex, file
// order) and prints a JSON object of timings. The mesh is read with our own
// loader and handed to CGAL vertex by vertex, so vertex ids are the file's.
#include <CGAL/Heat_method_3/Surface_mesh_geodesic_distances_3.h>
#include <CGAL/Simple_cartesian.h>
#include <CGAL/Surface_mesh.h>
#include <CGAL/Surface_mesh_shortest_path.h>

#include <chrono>
#include <cstdio>
#include <fstream>
#include <limits>
#include <string>
#include <vector>

#include "core/mesh/mesh_io.h"
#include "nlohmann/json.hpp"

namespace {

using Kernel = CGAL::Simple_cartesian<double>;
using SurfaceMesh = CGAL::Surface_mesh<Kernel::Point_3>;
using VertexIndex = SurfaceMesh::Vertex_index;

double SecondsSince(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

void WriteF64(const std::string& path, const std::vector<double>& values) {
  std::ofstream(path, std::ios::binary)
      .write(reinterpret_cast<const char*>(values.data()), values.size() * sizeof(double));
}

template <typename Method>
std::vector<double> HeatField(SurfaceMesh& mesh, VertexIndex source, double* setup_s,
                              double* solve_s) {
  auto t = std::chrono::steady_clock::now();
  CGAL::Heat_method_3::Surface_mesh_geodesic_distances_3<SurfaceMesh, Method> heat(mesh);
  *setup_s = SecondsSince(t);
  t = std::chrono::steady_clock::now();
  auto distance = mesh.add_property_map<VertexIndex, double>("v:heat", 0).first;
  heat.add_source(source);
  heat.estimate_geodesic_distances(distance);
  *solve_s = SecondsSince(t);
  std::vector<double> out;
  for (VertexIndex v : mesh.vertices()) out.push_back(distance[v]);
  mesh.remove_property_map(distance);
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 4) {
    std::fprintf(stderr, "usage: cgal_peer MESH VERTEX OUT_PREFIX\n");
    return 2;
  }
  const std::string prefix = argv[3];
  auto soup = geodesic::ReadTriangleSoup(argv[1]);
  if (!soup.ok()) {
    std::fprintf(stderr, "cgal_peer: %s\n", std::string(soup.status().message()).c_str());
    return 1;
  }
  // CGAL's solvers cannot take vertices no face uses (the heat method's
  // Laplacian turns singular), so those are left out and reported as +inf.
  const size_t file_vertices = soup->positions.size();
  std::vector<int64_t> cgal_id(file_vertices, -1);
  std::vector<size_t> file_id;
  SurfaceMesh mesh;
  for (const auto& t : soup->triangles) {
    for (auto v : t) {
      if (cgal_id[v] >= 0) continue;
      cgal_id[v] = file_id.size();
      file_id.push_back(v);
    }
  }
  for (size_t v : file_id) {
    const auto& p = soup->positions[v];
    mesh.add_vertex(Kernel::Point_3(p.x, p.y, p.z));
  }
  size_t refused = 0;
  for (const auto& t : soup->triangles) {
    if (mesh.add_face(VertexIndex(cgal_id[t[0]]), VertexIndex(cgal_id[t[1]]),
                      VertexIndex(cgal_id[t[2]])) == SurfaceMesh::null_face()) {
      ++refused;
    }
  }
  const size_t source_file_id = std::stoul(argv[2]);
  if (source_file_id >= file_vertices || cgal_id[source_file_id] < 0) {
    std::fprintf(stderr, "cgal_peer: vertex %zu is not on a face\n", source_file_id);
    return 1;
  }
  const VertexIndex source(cgal_id[source_file_id]);
  const size_t n = file_vertices;
  // Back to file order, +inf where CGAL had no vertex.
  auto in_file_order = [&](const std::vector<double>& cgal) {
    std::vector<double> out(n, std::numeric_limits<double>::infinity());
    for (size_t i = 0; i < file_id.size(); ++i) out[file_id[i]] = cgal[i];
    return out;
  };

  double heat_setup, heat_solve, idt_setup, idt_solve;
  WriteF64(prefix + ".heat.f64", in_file_order(HeatField<CGAL::Heat_method_3::Direct>(
                                     mesh, source, &heat_setup, &heat_solve)));
  WriteF64(prefix + ".heat-idt.f64",
           in_file_order(HeatField<CGAL::Heat_method_3::Intrinsic_Delaunay>(
               mesh, source, &idt_setup, &idt_solve)));

  using Traits = CGAL::Surface_mesh_shortest_path_traits<Kernel, SurfaceMesh>;
  auto t = std::chrono::steady_clock::now();
  CGAL::Surface_mesh_shortest_path<Traits> exact(mesh);
  exact.add_source_point(source);
  exact.build_sequence_tree();
  std::vector<double> field(mesh.number_of_vertices(), std::numeric_limits<double>::infinity());
  for (VertexIndex v : mesh.vertices()) {
    const double d = exact.shortest_distance_to_source_points(v).first;
    if (d >= 0) field[v.idx()] = d;
  }
  const double exact_s = SecondsSince(t);
  WriteF64(prefix + ".exact.f64", in_file_order(field));
  const nlohmann::ordered_json timings = {{"vertices", n},
                                          {"refused_faces", refused},
                                          {"heat_setup_seconds", heat_setup},
                                          {"heat_solve_seconds", heat_solve},
                                          {"heat_idt_setup_seconds", idt_setup},
                                          {"heat_idt_solve_seconds", idt_solve},
                                          {"exact_seconds", exact_s}};
  std::printf("%s\n", timings.dump().c_str());
  return 0;
}
