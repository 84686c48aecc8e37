#!/usr/bin/env bash
# Installs what geodesicd needs from Debian 12 packages (idempotent,
# non-interactive), then configures and builds it in Release mode into build/.
#   scripts/setup.sh               test packages too; builds everything (binaries,
#     tests, benchmarks): what scripts/test.sh runs
#   scripts/setup.sh --build-only  only what the daemon and CLI need, and only
#     those two binaries (the quick start, and the container's build stage)
#   scripts/setup.sh --deps        install the packages, build nothing
#   scripts/setup.sh --with-nginx  also nginx, for the deploy routing test
#     (CI only: Debian's package starts a system nginx on port 80, which this
#     stops again; a developer machine rarely wants that)
#   scripts/setup.sh --with-fuzz   also clang-14 and its sanitizer/libFuzzer
#     runtimes, for hunting with scripts/fuzz.sh (CI replays the corpus in
#     its ASan build instead: scripts/sanitize.sh)
set -euo pipefail
cd "$(dirname "$0")/.."
deps_only=false
build_only=false
with_nginx=false
with_fuzz=false
for arg in "$@"; do
  case "$arg" in
    --deps) deps_only=true ;;
    --build-only) build_only=true ;;
    --with-nginx) with_nginx=true ;;
    --with-fuzz) with_fuzz=true ;;
    *) echo "setup: unknown option $arg" >&2; exit 2 ;;
  esac
done

BUILD_PACKAGES=(
  build-essential cmake ninja-build pkg-config git ccache
  libgrpc++-dev libgrpc-dev protobuf-compiler-grpc libprotobuf-dev protobuf-compiler
  libabsl-dev libopenmesh-dev libtbb-dev libxxhash-dev libnanoflann-dev libcli11-dev nlohmann-json3-dev libboost-dev libyaml-cpp-dev libzip-dev
  libgiftiio-dev libexpat1-dev zlib1g-dev
  libssl-dev
)
# Tests, benchmarks, the viewer's browser test and the Python package's.
TEST_PACKAGES=(
  libgtest-dev libgmock-dev libbenchmark-dev libcgal-dev libeigen3-dev
  python3 python3-grpcio python3-protobuf python3-numpy python3-scipy python3-yaml python3-matplotlib python3-nibabel openssl
  libjs-three chromium chromium-driver python3-selenium curl universal-ctags
  python3-venv python3-pip python3-setuptools python3-wheel
)
PACKAGES=("${BUILD_PACKAGES[@]}")
$build_only || PACKAGES+=("${TEST_PACKAGES[@]}")

$with_nginx && [ ! -x /usr/sbin/nginx ] && PACKAGES+=(nginx-light)
$with_fuzz && PACKAGES+=(clang-14 libclang-rt-14-dev)
# The Node client's tests: Debian's nodejs and npm only where they are missing
# (a nodesource node brings its own npm, which Debian's npm would conflict with).
if ! $build_only; then
  command -v node >/dev/null || PACKAGES+=(nodejs)
  command -v npm >/dev/null || PACKAGES+=(npm)
fi
missing=()
for p in "${PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
SUDO=""
[ "$(id -u)" -eq 0 ] || SUDO="sudo"
if ((${#missing[@]})); then
  echo "setup: installing ${missing[*]}"
  $SUDO env DEBIAN_FRONTEND=noninteractive apt-get update -qq
  $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
    "${missing[@]}" >/dev/null
fi
if $with_nginx && [[ " ${missing[*]} " == *" nginx-light "* ]]; then
  # The tests run their own nginx as this user on a free loopback port.
  $SUDO systemctl disable --now nginx >/dev/null 2>&1 || $SUDO service nginx stop >/dev/null 2>&1 || true
fi
# The Node client (client/node): its packages, installed again only when the
# lock changed since the last install, and compiled (dist/) for its tests
# when a source changed since the last compile (tsc takes seconds even then).
if ! $build_only; then
  lock=client/node/package-lock.json stamp=client/node/node_modules/.setup-lock
  if ! cmp -s "$lock" "$stamp"; then
    (cd client/node && npm ci --no-audit --no-fund --loglevel=error >/dev/null)
    cp "$lock" "$stamp"
  fi
  built=client/node/dist/.setup-built
  if ! $deps_only && { [ ! -e "$built" ] || [ -n "$(find client/node/src client/node/tsconfig.json \
      client/node/package.json proto/geodesic/v1/geodesic.proto -newer "$built")" ]; }; then
    (cd client/node && npm run --silent build)
    touch "$built"
  fi
fi
$deps_only && exit 0

# One build/ for both: the quick start configures it without tests, the test
# command configures it again with them, and what both build is compiled once.
if $build_only; then
  cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release \
    -DGEODESIC_BUILD_TESTS=OFF -DGEODESIC_BUILD_BENCH=OFF
  cmake --build build -j"$(nproc)" --target geodesicd geodesic
else
  cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release \
    -DGEODESIC_BUILD_TESTS=ON -DGEODESIC_BUILD_BENCH=ON
  cmake --build build -j"$(nproc)"
fi
