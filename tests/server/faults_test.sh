#!/usr/bin/env bash
# Faults: kill -9 during a build and during a graph write, graph files
# truncated, deleted or replaced under a running daemon. After each, nothing
# untrustworthy is served and the daemon keeps serving.
# With --full-disk, only a full disk while writing a graph: it mounts a small
# tmpfs, so it needs root; without root it exits 77 (skipped), and as root a
# mount that fails is a failure, not a skip.
# Usage: faults_test.sh BUILD_BIN_DIR SOURCE_DIR [--full-disk]
set -uo pipefail
bin=$1
src=$2
full_disk=${3:-}
work=$(mktemp -d)
graphs=$work/graphs
source "$(dirname "$0")/daemon.sh"
tmpfs=
cleanup() {
  daemon_cleanup
  [ -n "$tmpfs" ] && umount "$tmpfs" 2>/dev/null
  rm -rf "$work"
}
trap cleanup EXIT
# --min-epsilon: the kill below needs a build that takes seconds.
start_daemon() {  # start_daemon GRAPH_DIR
  daemon_start "$bin" "$work" --mesh-root "$src/data" --log-level warning --build-threads 1 \
    --min-epsilon 1e-5 --graph-dir "$@" || exit 1
  retry_for 10 quietly cli meshes || daemon_fail "geodesicd does not answer"
}
stop_daemon() { daemon_stop; }
cli() { timeout 120 "$bin/geodesic" --server "127.0.0.1:$port" "$@"; }
graph_field() { cli --json --eps "$1" graph --wait | json "d[\"$2\"]"; }
offline_distance() {
  "$bin/geodesicd" distance --mesh "$src/data/spot.obj" --graph "$1" --from v:5 --to v:2500 --json |
    json 'd["distance"]'
}
daemon_distance() { cli --json --eps "$1" distance --from v:5 --to v:2500 | json 'd[0]["distance"]'; }
finish() {
  [ "$failures" = 0 ] || { echo "--- daemon log"; cat "$work/daemon.log"; }
  exit $((failures > 0))
}

# A full disk while building a graph into its file: the graph fails,
# naming the file, leaves no partial or temporary file, and the daemon keeps
# serving.
if [ "$full_disk" = --full-disk ]; then
  if [ "$(id -u)" != 0 ]; then
    echo "skip: mounting a small tmpfs needs root"
    exit 77
  fi
  mkdir -p "$work/full"
  mount -t tmpfs -o size=256k tmpfs "$work/full" ||
    { echo "FAIL cannot mount a tmpfs, although root"; exit 1; }
  tmpfs=$work/full
  start_daemon "$tmpfs"
  # One look: asked for again, a failed graph starts again.
  failed=$(cli --json --eps 0.01 graph --wait)
  check "full disk: the graph fails" test "$(json 'd["state"]' <<<"$failed")" = failed
  check "full disk: the error names the graph's file ($failed)" \
    grep -q "$tmpfs/[0-9a-f]*-eps0.01-r[0-9]*.dgg" <<<"$failed"
  # The catalog and its lock (it records the sample's graphs) are all there is.
  left=$(ls "$tmpfs" | grep -vx -e catalog.json -e catalog.lock)
  check "full disk: no graph file left behind ($left)" test -d "$tmpfs" -a -z "$left"
  check "full disk: the daemon still answers" quietly cli meshes
  stop_daemon
  finish
fi

# kill -9 in the middle of a build: no graph file appears, and a restart
# builds again rather than trusting anything left behind. At eps 1e-5 spot
# takes seconds to build on one thread (2e-4 took one: often done before the
# kill).
slow=0.00001
start_daemon "$graphs"
cli --eps $slow graph >/dev/null
graph_state() { cli --json --eps $slow graph | json 'd["state"] + "/" + str(d["from_file"])'; }
state=
for _ in $(seq 200); do
  state=$(graph_state)
  [ "$state" = building/False ] && break; sleep 0.05
done
sleep 0.5
check "the build is running when the daemon is killed" test "$(graph_state)" = building/False
daemon_kill
# The build's draft (its edges, under a temporary name) may stay: a
# temporary file, never mapped, like a killed write's below.
check "kill -9 during a build leaves no graph file" \
  test -d "$graphs" -a -z "$(ls "$graphs" | grep 'eps1e-05' | grep -v '\.dgg\.tmp\.')"
start_daemon "$graphs"
cli --eps $slow graph >/dev/null
# A fresh request is queued, then either mapped from a file (loading, then
# ready with from_file) or built: wait until it is one or the other.
for _ in $(seq 200); do
  state=$(graph_state)
  case $state in queued/* | loading/*) sleep 0.05 ;; *) break ;; esac
done
check "after restart the interrupted graph is built again, not mapped ($state)" \
  test "$state" = building/False
cli --eps $slow graph --cancel >/dev/null

# kill -9 in the middle of a graph write leaves a temporary file (simulated
# here: the first half of a real graph under the writer's temporary name).
# A restart never maps it, builds the graph again, and removes temporaries
# too old to belong to a live writer (replicas may share the directory).
graph_field 0.01 state >/dev/null
stop_daemon
good=$(ls "$graphs"/*eps0.01-r*.dgg)
size=$(stat -c %s "$good")
head -c $((size / 2)) "$good" > "$good.tmp.4242.beef"
touch -d '2 hours ago' "$good.tmp.4242.beef"
head -c $((size / 2)) "$good" > "$good.tmp.4343.cafe"
mv "$good" "$work/good.dgg"
start_daemon "$graphs"
check "a half-written temporary file is not mapped" test "$(graph_field 0.01 from_file)" = False
check "the rebuilt graph answers like the good one" \
  same_number "$(daemon_distance 0.01)" "$(offline_distance "$work/good.dgg")"
check "an old temporary file is removed at start" test ! -e "$good.tmp.4242.beef"
check "a recent temporary file (a live writer's) is left alone" test -e "$good.tmp.4343.cafe"

# A graph file truncated or bit-flipped by something else is rejected (moved
# aside for inspection) and rebuilt, never served.
stop_daemon
truncate -s $((size - 100)) "$good"
start_daemon "$graphs"
check "a truncated graph file is rebuilt, not mapped" test "$(graph_field 0.01 from_file)" = False
check "the truncated file was moved aside" test -n "$(ls "$graphs" | grep rejected)"
stop_daemon
printf '\xff' | dd of="$good" bs=1 seek=$((size / 2)) conv=notrunc status=none
start_daemon "$graphs"
check "a bit-flipped graph file is rebuilt, not mapped" test "$(graph_field 0.01 from_file)" = False
check "and answers like the good one" \
  same_number "$(daemon_distance 0.01)" "$(offline_distance "$work/good.dgg")"

# A valid graph of another mesh (spot with one vertex nudged: same counts,
# another fingerprint) under this mesh's file name is refused, not served.
stop_daemon
awk '/^v / && !done { $2 = $2 + 0.001; done = 1 } { print }' "$src/data/spot.obj" > "$work/nudged.obj"
"$bin/geodesicd" build "$work/nudged.obj" --eps 0.01 --out "$work/nudged.dgg" >/dev/null 2>&1
cp "$work/nudged.dgg" "$good"
start_daemon "$graphs"
check "another mesh's graph is rebuilt, not mapped" test "$(graph_field 0.01 from_file)" = False
check "and the refusal says so, with both fingerprints" \
  grep -q "built for another mesh (fingerprint" "$work/daemon.log"
check "and answers like the good one" \
  same_number "$(daemon_distance 0.01)" "$(offline_distance "$work/good.dgg")"

# Files deleted or replaced (by rename, as every writer here does) under a
# running daemon: it keeps serving the graph it mapped.
stop_daemon
start_daemon "$graphs"
check "graph mapped from the directory" test "$(graph_field 0.01 from_file)" = True
before=$(daemon_distance 0.01)
rm "$good"
check "graph file deleted under the daemon: still serving" \
  same_number "$(daemon_distance 0.01)" "$before"
head -c 10000 /dev/urandom > "$work/garbage"
mv "$work/garbage" "$good"
check "graph file replaced under the daemon: still serving" \
  same_number "$(daemon_distance 0.01)" "$before"
stop_daemon

finish
