#!/usr/bin/env bash
# A graph built in parts (geodesicd build --part I/N, on any machines) and
# merged equals the single-machine build byte for byte; parts that do not fit
# together are refused with a message naming the problem.
# Usage: distributed_build_test.sh BUILD_BIN_DIR SOURCE_DIR
set -uo pipefail
bin=$1
mesh=$2/data/spot.obj
work=$(mktemp -d)
source "$(dirname "$0")/daemon.sh"
trap 'daemon_cleanup; rm -rf "$work"' EXIT
geodesicd() { timeout 300 "$bin/geodesicd" "$@"; }

geodesicd build "$mesh" --eps 0.005 --threads 1 --quiet --out "$work/single.dgg" >/dev/null
for i in 0 1 2; do
  geodesicd build "$mesh" --eps 0.005 --threads 2 --quiet --part "$i/3" --out "$work/p$i.part" >/dev/null
done
geodesicd merge "$mesh" "$work/p2.part" "$work/p0.part" "$work/p1.part" --quiet \
  --out "$work/merged.dgg" >/dev/null
check "3 parts merged equal the single build byte for byte" \
  same_file "$work/single.dgg" "$work/merged.dgg"
check "merged graph passes full validation" quietly geodesicd info "$work/merged.dgg"

geodesicd merge "$mesh" "$work/p0.part" "$work/p2.part" --out "$work/x.dgg" 2>"$work/e1"
check "a missing part is named" grep -q "no part covers vertices" "$work/e1"
geodesicd merge "$mesh" "$work/p0.part" "$work/p0.part" "$work/p1.part" "$work/p2.part" \
  --out "$work/x.dgg" 2>"$work/e2"
check "an overlapping part is named" grep -q "two parts cover vertex" "$work/e2"
cp "$work/p1.part" "$work/flipped.part"
size=$(stat -c %s "$work/flipped.part")
printf '\x55' | dd of="$work/flipped.part" bs=1 seek=$((size - 7)) conv=notrunc status=none
geodesicd merge "$mesh" "$work/p0.part" "$work/flipped.part" "$work/p2.part" \
  --out "$work/x.dgg" 2>"$work/e3"
check "a corrupt part is detected" grep -q "flipped.part: checksum mismatch" "$work/e3"
geodesicd build "$mesh" --eps 0.01 --quiet --part 1/3 --out "$work/other_eps.part" >/dev/null
geodesicd merge "$mesh" "$work/p0.part" "$work/other_eps.part" "$work/p2.part" \
  --out "$work/x.dgg" 2>"$work/e4"
check "parts of another epsilon are refused" grep -q "epsilon 0.01" "$work/e4"
# Parts record the whole build: pruning and exact fans must agree too, and
# the graph takes the parts' record (a flag given must match it).
geodesicd build "$mesh" --eps 0.005 --quiet --prune --part 1/3 --out "$work/pruned.part" >/dev/null
geodesicd merge "$mesh" "$work/p0.part" "$work/pruned.part" "$work/p2.part" \
  --out "$work/x.dgg" 2>"$work/e6"
check "parts built with other pruning are refused by field" grep -q "prune_redundant true, not false" "$work/e6"
for i in 0 1 2; do
  geodesicd build "$mesh" --eps 0.005 --quiet --exact-fans --part "$i/3" --out "$work/xf$i.part" >/dev/null
done
geodesicd merge "$mesh" "$work/p0.part" "$work/xf1.part" "$work/p2.part" \
  --out "$work/x.dgg" 2>"$work/e7"
check "parts built with other fans are refused by field" grep -q "exact_fans true, not false" "$work/e7"
geodesicd merge "$mesh" "$work/xf0.part" "$work/xf1.part" "$work/xf2.part" --prune \
  --out "$work/x.dgg" 2>"$work/e8"
check "a merge flag the parts contradict is refused" grep -q "which the flags given contradict" "$work/e8"
check "no output written by failed merges" test ! -e "$work/x.dgg"
geodesicd merge "$mesh" "$work/xf0.part" "$work/xf1.part" "$work/xf2.part" --quiet \
  --out "$work/xf.dgg" >/dev/null
check "the merged graph carries the parts' exact fans" \
  test "$(geodesicd info "$work/xf.dgg" --json | python3 -c 'import json,sys; print(json.load(sys.stdin)["exact_fans"])')" = True
geodesicd build "$mesh" --eps 0.01 --part 3/3 --out "$work/y" 2>"$work/e5"
check "part index out of range" grep -q "index must be in" "$work/e5"

# A merge written with --graph-dir is what a daemon on that directory maps
# (the Kubernetes build Job's flow), instead of building.
geodesicd merge "$mesh" "$work/p0.part" "$work/p1.part" "$work/p2.part" --quiet \
  --graph-dir "$work/graphs" >/dev/null
daemon_start "$bin" "$work" --graph-dir "$work/graphs" --log-level warning || exit 1
from_file=
for _ in $(seq 50); do
  from_file=$(timeout 60 "$bin/geodesic" --server "127.0.0.1:$port" --json --eps 0.005 graph --wait 2>/dev/null |
    python3 -c 'import json,sys; print(json.load(sys.stdin)["from_file"])' 2>/dev/null) && break
  sleep 0.2
done
check "the daemon maps a graph merged into its --graph-dir" test "$from_file" = True
exit $((failures > 0))
