#!/usr/bin/env bash
# The test suite under sanitizers:
#   ASan+UBSan (build-asan): core and server unit tests (the accuracy
#     suites on the smaller shared meshes), the replay of the committed fuzz
#     corpus, and the daemon end-to-end, fault and security tests against an
#     instrumented daemon and CLI;
#   TSan (build-tsan): the core unit tests only, so only they are built
#     (concurrent queries and landmark preparation on one graph). The
#     accuracy suites (*SharedMeshes*, CgalTruth) are left out:
#     single-threaded numerics under TSan's slowdown, already run plain
#     and under ASan; so are the scale tests (MeshScaleTest) and the
#     matrix tests (QueriesTest.*Matrix*, and the lane sweeps' and matrix
#     rows' tests: float32 rows, sparse rows, fans narrowed, bounded sweeps,
#     the matrix sweep's work), whose rows run on TBB, which TSan builds
#     keep to one thread (see below), and three checks of
#     single-threaded numerics (pairs against a Dijkstra, exact distances
#     on noisy tori, geodesic shooting), the slowest of their kind.
#     So is the 1-against-4-threads build
#     comparison: TSan builds keep TBB to one thread (core/base/thread_arena.h), so
#     it could only compare one thread with one thread.
# Debian's gRPC, Abseil, OpenMesh and TBB are not instrumented: TSan cannot
# see their synchronisation, which is why the daemon runs under ASan only.
#   scripts/sanitize.sh [address|thread]   (default: both)
set -euo pipefail
cd "$(dirname "$0")/.."
kinds=${1:-"address thread"}
for kind in $kinds; do
  dir=build-${kind/address/asan}
  dir=${dir/thread/tsan}
  cmake -S . -B "$dir" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DGEODESIC_SANITIZE="$kind" \
    -DGEODESIC_BUILD_BENCH=OFF >/dev/null
  if [ "$kind" = address ]; then
    # What the tests below run, not every target: CGAL's truth test and the
    # standalone query benchmark stay in the Release suite.
    cmake --build "$dir" -j"$(nproc)" --target core_tests server_tests geodesicd geodesic \
      geodesic_python_stubs mesh_reader_replay graph_file_replay surface_point_replay
    export ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1
    # The accuracy suites run on every shared mesh in the Release suite; here on the
    # smaller ones (spot, camelhead, fertility, blade), whose code paths are the same: the
    # largest meshes' instrumented runs took a quarter of this lane. So do CGAL's truth
    # comparison, the blade's two pseudo-vertex builds at small epsilon and camelhead's
    # exact pairs: single-threaded numerics whose paths smaller cases here take too.
    ctest --test-dir "$dir" --output-on-failure -j2 --timeout 1800 -L "core|server-unit|fuzz" \
      -E "CgalTruth|cgal_truth_test|PseudoVerticesOnSharedMeshes|SharedAccuracyTest.*/(armadillo|bunny)_eps|CertifiedOnSharedMeshesTest.*/fertility|(MatrixPairsTest|TruthTest|ExactPropertyTest).*\"(armadillo|bunny)\"|ExactPairsTest.*\"(fertility|camelhead)\""
    ctest --test-dir "$dir" --output-on-failure -j2 --timeout 1800 -R "server_e2e|server_faults|server_security|distributed_build"
  else
    # Only the core tests run under TSan: build just those, not the server.
    cmake --build "$dir" -j"$(nproc)" --target core_tests
    export TSAN_OPTIONS="halt_on_error=1 second_deadlock_stack=1"
    ctest --test-dir "$dir" --output-on-failure -j2 --timeout 1800 -L core \
      -E "SharedMeshes|CgalTruth|MeshScaleTest|BuildIsIdenticalWhateverTheThreadCount|QueriesTest\.(Exact)?Matrix|QueriesTest\.(Float32Rows|SparseRows|LaneSweeps|NarrowedFans|FansNarrowedNearby|BoundedSweeps)|AMatrixSweepDoesThePinnedWork|PairsEqualADijkstraRelaxingEveryEdge|OnNoisyTori|ShotStripTest"
  fi
done
