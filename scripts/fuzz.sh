#!/usr/bin/env bash
# Builds the libFuzzer targets with clang-14 (ASan+UBSan) into build-fuzz/
# and runs each for N seconds from its seed corpus; fails on any crash,
# leak, sanitizer report or timeout. Crash inputs are left in build-fuzz/.
#   scripts/fuzz.sh [--seconds N]     (default 60 per target)
#   scripts/fuzz.sh --runs N          N inputs per target with a fixed seed,
#     from the seeds and regression inputs only: the same inputs on every
#     machine, so CI goes red on a regression, not on a lucky new find
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=60
limit=()
case "${1:-}" in
  --seconds) seconds=$2 ;;
  --runs) limit=(-runs="$2" -seed=1) ;;
esac
[ ${#limit[@]} -eq 0 ] && limit=(-max_total_time="$seconds")
CC=clang-14 CXX=clang++-14 cmake -S . -B build-fuzz -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DGEODESIC_FUZZ=ON >/dev/null
cmake --build build-fuzz -j"$(nproc)"
status=0
for target in mesh_reader graph_file surface_point; do
  corpus=build-fuzz/corpus/$target
  mkdir -p "$corpus"
  seeds=(tests/fuzz/corpus/"$target"*)
  echo "fuzz: $target (${limit[*]})"
  if ! (cd build-fuzz && ./bin/${target}_fuzzer "${limit[@]}" -timeout=10 \
        -rss_limit_mb=2048 -max_len=65536 -print_final_stats=1 "../$corpus" "${seeds[@]/#/../}" \
        > "fuzz-$target.log" 2>&1); then
    echo "fuzz: $target FAILED (build-fuzz/fuzz-$target.log)"; tail -n 30 "build-fuzz/fuzz-$target.log"
    status=1
  else
    grep -E "stat::number_of_executed_units|cov:" "build-fuzz/fuzz-$target.log" | tail -n 2
  fi
done
exit $status
