#!/usr/bin/env bash
# The README's first command: set up, build, and run the main job on the
# bundled sample mesh (data/spot.obj).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
echo "== mesh diagnostics"
build/bin/geodesicd info data/spot.obj
echo "== building the discrete geodesic graph (eps 1e-3)"
build/bin/geodesicd build data/spot.obj --eps 1e-3 --out "$out/spot.dgg"
echo "== distance field from vertex 0"
build/bin/geodesicd field --mesh data/spot.obj --graph "$out/spot.dgg" --source v:0 --out "$out/field.f64"
echo "== point-to-point distance and path between two surface points"
build/bin/geodesicd distance --mesh data/spot.obj --graph "$out/spot.dgg" \
  --from f:0:0.2,0.3,0.5 --to v:1500 --path
