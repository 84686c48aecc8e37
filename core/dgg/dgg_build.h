// Construction of the discrete geodesic graph: Algorithm 1 of the DGG paper
// (candidate edges with early termination, pruning of redundant edges,
// pseudo vertices on anisotropic meshes), in parallel.
#ifndef GEODESIC_CORE_DGG_DGG_BUILD_H_
#define GEODESIC_CORE_DGG_DGG_BUILD_H_

#include <functional>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/statusor.h"
#include "core/dgg/dgg_graph.h"
#include "core/mesh/mesh.h"

namespace geodesic {

// Where a build keeps its graph's edge array: a file descriptor open for
// reading and writing and a page-aligned offset into it (GraphFileDraft), or
// fd -1 for anonymous memory.
struct DggEdgeFile {
  int fd = -1;
  uint64_t offset = 0;
  // Asked, if set, before the file is made to hold `bytes` bytes of edges
  // past the offset in all (it grows twice, once its edges are counted and
  // again with the edges found from one end only): a caller that keeps a
  // directory within a disk budget admits the growth here, before the disk
  // fills. An error stops the build with it.
  std::function<absl::Status(uint64_t bytes)> admit_growth;
};

struct DggBuildOptions {
  // What to build. params.candidate_rule must be kCandidateRuleVersion:
  // this code makes graphs of no other rule.
  DggParams params;
  int threads = 0;  // 0: all hardware threads
  // Candidate propagation stops rays that a route through a window's corner
  // already serves (DirectOptions::stop_at_corners). False: plain Algorithm
  // 1, for benchmarks; the graph may differ, the accuracy bound does not.
  bool stop_at_corners = true;
  // Bytes of candidate edges the candidate phase keeps in memory (0: no
  // limit); beyond it they go to an unlinked file in spill_dir (the current
  // directory when empty) and are read back once, in a stream. The rest of
  // the build works on one edge array the size of the graph's, in place.
  uint64_t candidate_memory_limit = 0;
  // With params.pseudo_vertices: the most pseudo vertices per mesh vertex
  // the build may add (0: no limit). Past it the build fails with
  // FAILED_PRECONDITION giving the estimated cost, as soon as it is passed:
  // at 1 the graph stays within about twice the plain one's size and time.
  double pseudo_vertex_limit = 0;
  std::string spill_dir;
  // Asked, if set, before the spill file is made to hold `bytes` bytes in
  // all, and with 0 once it is gone (read back, or the build ended): a
  // caller that keeps spill_dir within a disk budget admits the spill here,
  // as DggEdgeFile::admit_growth the edges. An error stops the build with it.
  std::function<absl::Status(uint64_t bytes)> admit_spill;
  // Keep the edge array in this file (GraphFileDraft::edge_file) instead of
  // anonymous memory. Ignored with pseudo vertices, which change the node
  // count the file's layout was made for.
  DggEdgeFile edge_file;
  // Called now and then from any build thread with the current phase
  // ("candidates", "pruning", "pseudo", "fans") and the fraction of the whole
  // build done, in [0, 1]. Returning false cancels the build (CANCELLED).
  std::function<bool(std::string_view phase, double fraction)> progress;
};

struct DggBuildStats {
  double candidate_seconds = 0;
  double pruning_seconds = 0;
  double pseudo_seconds = 0;
  double fan_seconds = 0;
  double total_seconds = 0;
  uint64_t candidate_edges = 0;  // undirected, before pruning
  // Edges as each vertex's own propagation found them, before an edge found
  // from either end becomes one undirected edge. FastDGG keeps exactly
  // these, as a directed graph, and its "average degree" is their number
  // per vertex; ours (average_degree) counts the undirected graph the
  // queries search, which holds both directions of each.
  uint64_t found_edges = 0;
  uint64_t edges = 0;            // undirected, in the final graph
  uint64_t windows_created = 0;  // by the candidate propagation, all sources
  uint64_t spilled_bytes = 0;    // candidate runs that went to disk
  uint32_t pseudo_vertices = 0;
  // Geodesics shot into the gaps between edge directions, and those of them
  // whose end point needed a propagation to decide (section 4.3).
  uint64_t pseudo_shots = 0;
  uint64_t pseudo_propagations = 0;
  uint32_t max_degree = 0;
  double average_degree = 0;
  double average_fan = 0;  // edges a node reached along an edge relaxes
};

// The build's phases (section 4), each edge given the fan that paths of at
// most two edges allow: a sound graph, but not yet the one a build makes.
// core/query/build_dgg.h's BuildDgg narrows the fans further with the
// solver's own sweeps, as every graph served is built, and is what callers
// use. Fails with INVALID_ARGUMENT for epsilon outside (0, 1) or NaN, and
// with CANCELLED when the progress callback asks to stop; reports progress
// up to 0.97 (the narrowing takes the rest).
absl::StatusOr<std::shared_ptr<const DggGraph>> BuildDggWithTwoEdgeFans(
    const Mesh& mesh, const DggBuildOptions& options, DggBuildStats* stats = nullptr);

// A lower estimate of the bytes of the graph of a mesh with `vertices`
// vertices at `epsilon`, to refuse builds that cannot fit a memory budget
// before spending minutes on them. DGG degree grows like 1/sqrt(epsilon);
// it assumes a degree well below every average degree of BENCHMARKS.md's
// "Graph construction" table (compared as degree times sqrt(epsilon)), so
// that the estimate stays below the real size on meshes not measured.
uint64_t EstimateDggBytesLowerBound(uint64_t vertices, double epsilon);

// What a build will likely cost: its graph file's bytes and its time on one
// thread. A central estimate, not a bound (EstimateDggBytesLowerBound is the
// bound): for admission and scheduling, which need the order of magnitude.
struct DggBuildEstimate {
  uint64_t bytes = 0;
  double seconds = 0;  // on one thread
};
// Power laws in epsilon per vertex, fitted to BENCHMARKS.md's build table
// (every shared mesh at three epsilons); pseudo vertices scale them by
// factors fitted to its pseudo-vertex table, whose anisotropic mesh is the
// worst case measured. Epsilon outside (0, 1) gives UINT64_MAX bytes.
DggBuildEstimate EstimateDggBuild(uint64_t num_vertices, double epsilon, bool pseudo);

// Distributed builds. The candidate phase (the direct geodesics from every
// vertex) is most of the work and independent per source, so it splits into
// vertex ranges built anywhere; merging the parts runs the remaining phases
// and gives the same graph, bit for bit, as a whole build.
struct DggCandidatePart {
  DggParams params;
  uint64_t mesh_fingerprint = 0;
  uint32_t num_vertices = 0;       // of the whole mesh
  uint32_t begin = 0, end = 0;     // the sources of this part
  uint64_t windows_created = 0;    // by this part's propagation
  std::vector<uint64_t> offsets;   // end - begin + 1 entries into `edges`
  std::vector<DggHalfEdge> edges;  // per source, sorted by target id
};

// Part `index` (0-based) of `count` equal vertex ranges.
absl::StatusOr<DggCandidatePart> BuildDggCandidatePart(const Mesh& mesh,
                                                       const DggBuildOptions& options,
                                                       uint32_t index, uint32_t count);

// A part to merge, loaded only when the merge reaches it, so that a merge
// holds one part at a time beside the graph it makes.
struct DggPartSource {
  std::string name;        // for messages: the part's file
  DggCandidatePart index;  // everything but the edges
  // The whole part; its offsets must equal the index's.
  std::function<absl::StatusOr<DggCandidatePart>()> load;
};

// Joins parts (in any order) that together cover every vertex exactly once,
// all built for this mesh with the same parameters, which the graph takes
// (options.params is ignored), with fans as BuildDggWithTwoEdgeFans gives
// them (core/query/build_dgg.h's MergeDggParts narrows them).
// FAILED_PRECONDITION names the part at fault and, for parameters, the field
// that differs.
absl::StatusOr<std::shared_ptr<const DggGraph>> MergeDggPartsWithTwoEdgeFans(
    const Mesh& mesh, std::vector<DggPartSource> parts, const DggBuildOptions& options,
    DggBuildStats* stats = nullptr);
// The same for parts in memory, named by their position.
absl::StatusOr<std::shared_ptr<const DggGraph>> MergeDggPartsWithTwoEdgeFans(
    const Mesh& mesh, std::vector<DggCandidatePart> parts, const DggBuildOptions& options,
    DggBuildStats* stats = nullptr);

}  // namespace geodesic

#endif  // GEODESIC_CORE_DGG_DGG_BUILD_H_
