#!/usr/bin/env bash
# The README's first command: install what the daemon and the CLI need, build
# only those two, start the daemon on the bundled sample mesh (data/spot.obj),
# query it with the CLI, stop it, and install the binaries under ~/.local
# (GEODESIC_PREFIX) for the README's other commands. The test packages and
# targets wait for scripts/test.sh. Elapsed times go to build/quickstart-times.tsv
# (scripts/ci_report.py puts them in docs/ci.md).
set -euo pipefail
cd "$(dirname "$0")/.."
start=$SECONDS
times=()
mark() { times+=("$1	$((SECONDS - start))"); }
bash scripts/setup.sh --build-only
mark built
port=${GEODESIC_PORT:-50051}
work=$(mktemp -d)
build/bin/geodesicd serve --listen "127.0.0.1:$port" --graph-dir "$work/graphs" \
  --log-level warning &
daemon=$!
trap 'kill "$daemon" 2>/dev/null; wait "$daemon" 2>/dev/null; rm -rf "$work"' EXIT
geodesic() { build/bin/geodesic --server "127.0.0.1:$port" "$@"; }
for _ in $(seq 50); do geodesic meshes >/dev/null 2>&1 && break; sleep 0.2; done
echo "== meshes"
geodesic meshes
echo "== graph of the sample mesh at eps 1e-3 (built in the background)"
geodesic graph --wait
echo "== distance and geodesic path between a point inside face 0 and vertex 1500"
geodesic path --from f:0:0.2,0.3,0.5 --to v:1500
mark first_answer
echo "== distance field from vertex 0"
geodesic field --source v:0 --out "$work/field.f64"
echo "== 2000 random point-to-point queries from 4 clients"
geodesic bench --count 2000 --concurrency 4
mark answered
# The README's commands call geodesicd and geodesic by name: install them (and
# the sample mesh and viewer they find beside them) under ~/.local.
prefix=${GEODESIC_PREFIX:-$HOME/.local}
cmake --install build --prefix "$prefix" >/dev/null
mark installed
echo "== installed geodesicd and geodesic in $prefix/bin"
case ":$PATH:" in
  *":$prefix/bin:"*) ;;
  *) echo "   add it to PATH:  export PATH=\"$prefix/bin:\$PATH\"" ;;
esac
printf '%s\n' "${times[@]}" > build/quickstart-times.tsv
echo "== first answer $(sed -n 's/^first_answer\t//p' build/quickstart-times.tsv) s after the start, all done in $((SECONDS - start)) s"
