#!/usr/bin/env bash
# The README's test command: installs the test packages that are missing,
# builds every target into build/ (what the quick start built is reused),
# and runs the suite. Extra arguments go to ctest (e.g. -R name, -L label).
# The tests on the shared meshes are registered when ../shared is found
# (GEODESIC_SHARED_DIR elsewhere; GEODESIC_REQUIRE_SHARED=1 makes it an error).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
ctest --test-dir build --output-on-failure -j"$(nproc)" --timeout 900 "$@"
