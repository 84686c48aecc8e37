#!/usr/bin/env bash
# End-to-end: a real daemon on 127.0.0.1 (port 0, read back), driven by the CLI.
# Usage: e2e_test.sh BUILD_BIN_DIR SOURCE_DIR
set -uo pipefail
bin=$1
src=$2
work=$(mktemp -d)
source "$(dirname "$0")/daemon.sh"
trap 'daemon_cleanup; rm -rf "$work"' EXIT
start_daemon() {
  daemon_start "$bin" "$work" --graph-dir "$work/graphs" --mesh-root "$src/data" \
    --log-level warning --pseudo-vertex-limit 0 "$@" || exit 1
  retry_for 10 quietly cli meshes || daemon_fail "geodesicd does not answer"
}
stop_daemon() { daemon_stop; }
cli() { timeout 120 "$bin/geodesic" --server "127.0.0.1:$port" "$@"; }

start_daemon
check "sample mesh registered" test "$(cli --json meshes | json 'd[0]["name"]')" = spot
check "sample mesh parsed and built the first time" \
  test "$(cli --json meshes | json 'd[0]["restored"]')" = False
state=$(cli --json --eps 0.01 graph --wait | json 'd["state"]')
check "graph builds to ready" test "$state" = ready
graph=$(ls "$work"/graphs/*eps0.01-r*.dgg)
check "graph persisted atomically (no temp files)" \
  test -s "$graph" -a "$(ls "$work/graphs" | grep -c tmp)" = 0

# Query results equal the offline core results on the same graph file.
cli --json --eps 0.01 distance --from f:10:0.2,0.3,0.5 --to v:2000 > "$work/d_daemon.json"
"$bin/geodesicd" distance --mesh "$src/data/spot.obj" --graph "$graph" \
  --from f:10:0.2,0.3,0.5 --to v:2000 --json > "$work/d_offline.json"
d1=$(json 'd[0]["distance"]' < "$work/d_daemon.json")
d2=$(json 'd["distance"]' < "$work/d_offline.json")
check "distance equals the offline result ($d1)" same_number "$d1" "$d2"
cli --eps 0.01 field --source v:7 --out "$work/f_daemon.f64" >/dev/null
"$bin/geodesicd" field --mesh "$src/data/spot.obj" --graph "$graph" --source v:7 --out "$work/f_offline.f64" >/dev/null
check "streamed field equals the offline field" same_file "$work/f_daemon.f64" "$work/f_offline.f64"
plen=$(cli --json --eps 0.01 path --from v:1 --to v:2500 | json 'len(d[0]["path"])')
check "path has points ($plen)" test "$plen" -gt 2
# The graph with pseudo vertices is its own graph: --wait watches it (not the
# plain one of the same eps), status tells the two apart, and its queries
# equal the offline ones on its file.
state=$(cli --json --eps 0.01 graph --pseudo-vertices --wait | json 'd["state"], d["pseudo_vertices"]')
check "pseudo-vertex graph builds to ready, watched as itself" test "$state" = "ready True"
check "status lists the pseudo-vertex graph beside the plain one" \
  test "$(cli --json status | json 'sorted(g["pseudo_vertices"] for g in d if g["epsilon"] == 0.01)')" = "[False, True]"
pgraph=$(ls "$work"/graphs/*eps0.01-pseudo-r*.dgg)
cli --eps 0.01 field --pseudo-vertices --source v:7 --out "$work/pf_daemon.f64" >/dev/null
"$bin/geodesicd" field --mesh "$src/data/spot.obj" --graph "$pgraph" --source v:7 --out "$work/pf_offline.f64" >/dev/null
check "pseudo-vertex field equals the offline one" same_file "$work/pf_daemon.f64" "$work/pf_offline.f64"
check "and differs from the plain graph's field" different_files "$work/pf_daemon.f64" "$work/f_daemon.f64"
pd=$(cli --json --eps 0.01 --pseudo-vertices distance --from f:10:0.2,0.3,0.5 --to v:2000 | json 'd[0]["distance"]')
poff=$("$bin/geodesicd" distance --mesh "$src/data/spot.obj" --graph "$pgraph" \
  --from f:10:0.2,0.3,0.5 --to v:2000 --json | json 'd["distance"]')
check "pseudo-vertex distance equals the offline one ($pd)" same_number "$pd" "$poff"
# A non-manifold upload (a bow tie: two triangles sharing only a vertex) is
# refused naming the vertex, and registered with repair, the copy listed.
printf 'v 0 0 0\nv 1 0 0\nv 0 1 0\nv -1 0 0\nv 0 -1 0\nf 1 2 3\nf 1 4 5\n' > "$work/bowtie.obj"
cli load --upload "$work/bowtie.obj" 2>"$work/e_bowtie"
check "a non-manifold upload is refused, naming the vertex" \
  grep -q "INVALID_ARGUMENT.*vertex 0 is non-manifold.*repair_non_manifold" "$work/e_bowtie"
copies=$(cli --json load --upload "$work/bowtie.obj" --repair-non-manifold | json 'd["vertex_copies"]')
check "with repair it registers, listing the copy ($copies)" \
  test "$copies" = "[{'original': 0, 'copy': 5}]"
cli --mesh bowtie unload >/dev/null
# xyz: points report how far they were snapped, as the offline commands do.
snapd=$(cli --json --eps 0.01 distance --from v:1 --to xyz:0.3,0.1,0 | json 'd[0]["to_snap_distance"]')
offd=$("$bin/geodesicd" distance --mesh "$src/data/spot.obj" --graph "$graph" --from v:1 \
  --to xyz:0.3,0.1,0 --json | json 'd["to_snap_distance"]')
check "snap distance reported ($snapd) and equal to the offline one" same_number "$snapd" "$offd"
# Farthest-point sampling on the server: distinct vertices, one per seed.
s1=$(cli --json --eps 0.01 sample --count 6 --seed 3 | json 'd["vertices"]')
s2=$(cli --json --eps 0.01 sample --count 6 --seed 3 | json 'd["vertices"]')
check "sample: 6 distinct vertices, the same for one seed" \
  test "$(python3 -c "print(len(set($s1)))")" = 6 -a "$s1" = "$s2"
radius=$(cli --json --eps 0.01 sample --count 6 --seed 3 | json 'd["covering_radius"]')
check "sample: a finite covering radius ($radius)" python3 -c "import math,sys; sys.exit(not 0 < $radius < math.inf)"
# Result files by extension, as the offline commands write them.
cli --eps 0.01 field --source v:7 --source v:900 --out "$work/f_daemon.npy" --labels-out "$work/l_daemon.csv" >/dev/null
"$bin/geodesicd" field --mesh "$src/data/spot.obj" --graph "$graph" --source v:7 --source v:900 \
  --out "$work/f_offline.npy" --labels-out "$work/l_offline.csv" >/dev/null
check "npy field equals the offline one" same_file "$work/f_daemon.npy" "$work/f_offline.npy"
check "Voronoi labels equal the offline ones" same_file "$work/l_daemon.csv" "$work/l_offline.csv"
cli --eps 0.01 field --source v:7 --out "$work/f.txt" 2>"$work/e_ext"
check "unknown field format refused" grep -q "'.txt'" "$work/e_ext"
check "nothing written for it" test ! -e "$work/f.txt"
cli --eps 0.01 path --from v:1 --to v:2500 --out "$work/p.obj" >/dev/null
check "path polyline written ($plen points)" same_number "$(grep -c '^v ' "$work/p.obj")" "$plen"

# Bad requests get precise codes and the daemon keeps serving.
cli --eps 0.01 distance --from v:999999 --to v:1 2>"$work/e1"; check "vertex id too large" grep -q OUT_OF_RANGE "$work/e1"
cli --eps 0.01 distance --from f:1:0.5,0.6,0.1 --to v:1 2>"$work/e2"; check "barycentrics not summing to 1" grep -q INVALID_ARGUMENT "$work/e2"
cli --mesh nosuch distance --from v:1 --to v:2 2>"$work/e3"; check "unknown mesh" grep -q NOT_FOUND "$work/e3"
cli --mesh evil load ../../../etc/passwd 2>"$work/e4"; check "path outside the mesh root" grep -q PERMISSION_DENIED "$work/e4"
for eps in 2 -0.1 nan 1e-9; do
  cli --eps "$eps" graph 2>"$work/e5"; check "epsilon $eps refused" grep -q INVALID_ARGUMENT "$work/e5"
  cli --eps "$eps" graph --cancel 2>"$work/e5"
  check "epsilon $eps refused by CancelGraph" grep -q INVALID_ARGUMENT "$work/e5"
done
cli --eps 0.01 distance --from f:1:-0.5,1.0,0.5 --to v:1 2>"$work/e8"; check "negative barycentric" grep -q INVALID_ARGUMENT "$work/e8"
cli --eps 0.01 distance --from f:1:nan,0.5,0.5 --to v:1 2>"$work/e9"; check "NaN barycentric" grep -q INVALID_ARGUMENT "$work/e9"
cli --eps 0.01 distance --from f:99999:0.2,0.3,0.5 --to v:1 2>"$work/e10"; check "face id too large" grep -q OUT_OF_RANGE "$work/e10"
printf 'OFF\n3 1 0\n0 0 0\n1 0 0\n' > "$work/broken.off"
cli --mesh broken load --upload "$work/broken.off" 2>"$work/e6"; check "truncated upload rejected" grep -q INVALID_ARGUMENT "$work/e6"
check "still serving after bad requests" cli meshes >/dev/null

# Concurrent clients.
failed=$(cli --json --eps 0.01 bench --concurrency 4 --count 400 | json 'd["failed"]')
check "concurrent queries all succeed" test "$failed" = 0

# Upload, then cancel a long build.
cli --mesh bigger load --upload "$src/data/spot.obj" >/dev/null
cli --mesh bigger --eps 0.0001 graph >/dev/null
sleep 0.5
cli --mesh bigger --eps 0.0001 graph --cancel >/dev/null
for _ in $(seq 100); do
  s=$(cli --json status | json '[g["state"] for g in d if g["epsilon"]==0.0001][0]')
  [ "$s" = cancelled ] && break; sleep 0.1
done
check "build cancelled" test "$s" = cancelled

# Restart: the graph is mapped again from the graph directory, not rebuilt.
stop_daemon
start_daemon
from_file=$(cli --json --eps 0.01 graph --wait | json 'd["from_file"]')
check "graph mapped again after restart" test "$from_file" = True
check "mesh restored from its snapshot after restart" \
  test "$(cli --json meshes | json 'd[0]["restored"]')" = True
vertices=$(cli --json meshes | json 'd[0]["diagnostics"]["vertices"]')
check "restored mesh keeps its diagnostics" test "$vertices" = 2930
cp "$src/data/spot.obj" "$work/spot_copy.obj"
restored=$(cli --mesh copy --json load --upload "$work/spot_copy.obj" | json 'd["restored"]')
check "an upload of the same bytes is restored too" test "$restored" = True

# Eviction under a small memory budget: the least recently used graph goes,
# and comes back (mapped from its file) on the next request.
stop_daemon
start_daemon --memory-limit 2500000
cli --eps 0.0001 graph 2>"$work/e11"  # --min-epsilon, yet over 2.5 MB
check "epsilon too small for the memory limit" grep -q "over the server's memory limit" "$work/e11"
cli --eps 0.01 graph --wait >/dev/null
cli --eps 0.02 graph --wait >/dev/null
s=$(cli --json status | json '[g["state"] for g in d if g["epsilon"]==0.01][0]')
check "least recently used graph evicted" test "$s" = evicted
# This limit leaves no room for a query beside the meshes: it is refused at
# once, naming the limit.
cli --eps 0.01 distance --from v:1 --to v:2 2>"$work/e7"
check "a query with no room beside the meshes is refused, naming the limit" \
  grep -q "RESOURCE_EXHAUSTED.*memory limit (2500000 bytes)" "$work/e7"
# Asked again, the evicted graph is mapped again from its file.
cli --eps 0.01 graph --wait >/dev/null
state=$(cli --json status | json '[g["state"] for g in d if g["epsilon"]==0.01][0]')
check "evicted graph comes back" test "$state" = ready

# Request limits: each over-limit request is RESOURCE_EXHAUSTED naming the
# limit, and the daemon keeps serving.
stop_daemon
start_daemon --max-pairs 2 --max-sources 1 --max-upload-bytes 1000
printf 'v:1 v:2\nv:3 v:4\nv:5 v:6\n' > "$work/three_pairs"
cli --eps 0.01 graph --wait >/dev/null
cli --eps 0.01 distance --pairs "$work/three_pairs" 2>"$work/e12"
check "pairs over --max-pairs refused" grep -q "RESOURCE_EXHAUSTED.*3 pairs exceed the limit of 2" "$work/e12"
cli --eps 0.01 field --source v:1 --source v:2 2>"$work/e13"
check "sources over --max-sources refused" grep -q "RESOURCE_EXHAUSTED.*2 sources exceed the limit of 1" "$work/e13"
cli --eps 0.01 matrix --source v:1 --target v:2 --target v:3 --target v:4 2>"$work/e14"
check "matrix over the limits refused" grep -q RESOURCE_EXHAUSTED "$work/e14"
cli --mesh toobig load --upload "$src/data/spot.obj" 2>"$work/e15"
check "upload over --max-upload-bytes refused" grep -q "RESOURCE_EXHAUSTED.*max-upload-bytes" "$work/e15"
check "within the limits still served" cli --eps 0.01 distance --from v:1 --to v:2
check "oversized upload left no mesh behind" \
  test "$(cli --json meshes | json '[m["name"] for m in d].count("toobig")')" = 0
# Meshes clients registered before the restarts are back, from the catalog.
check "uploaded meshes survive restarts (catalog)" \
  test "$(cli --json meshes | json 'sorted(m["name"] for m in d)')" = "['bigger', 'copy', 'spot']"

echo "$passes passed, $failures failed"
[ "$failures" = 0 ]
