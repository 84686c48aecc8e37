#!/usr/bin/env bash
# Builds the libFuzzer targets with clang-14 (ASan+UBSan) into build-fuzz/
# and runs them; fails on any crash, leak, sanitizer report or timeout.
# Crash inputs are left in build-fuzz/.
#   scripts/fuzz.sh --replay          every committed seed and regression input
#     once: the same inputs on every machine, so CI goes red on a regression
#   scripts/fuzz.sh [--seconds N]     mutate for N seconds per target (default
#     60), to hunt for new bugs
#   scripts/fuzz.sh --runs N          N mutated inputs per target with seed 1.
#     Not reproducible across runs: absl hash seeds and temporary file names
#     vary, and coverage feedback steers mutation, so this is for hunting too.
set -euo pipefail
cd "$(dirname "$0")/.."
mode=(-max_total_time=60)
case "${1:-}" in
  --replay) mode=(-runs=0) ;;
  --seconds) mode=(-max_total_time="$2") ;;
  --runs) mode=(-runs="$2" -seed=1) ;;
esac
CC=clang-14 CXX=clang++-14 cmake -S . -B build-fuzz -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DGEODESIC_FUZZ=ON >/dev/null
cmake --build build-fuzz -j"$(nproc)"
status=0
for target in mesh_reader graph_file surface_point; do
  corpus=build-fuzz/corpus/$target
  # Seeds, regression-* inputs and merged/ (a -merge=1 minimisation of
  # hunting corpora). Mutation reads both directories (recursively) and
  # writes new finds to the first; a replay runs each committed file once.
  mapfile -t seeds < <(find tests/fuzz/corpus/"$target" -type f | sort)
  inputs=("../$corpus" "../tests/fuzz/corpus/$target")
  [ "${mode[0]}" = -runs=0 ] && inputs=("${seeds[@]/#/../}")
  mkdir -p "$corpus"
  echo "fuzz: $target (${mode[*]}, ${#seeds[@]} committed inputs)"
  if ! (cd build-fuzz && ./bin/${target}_fuzzer "${mode[@]}" -timeout=10 \
        -rss_limit_mb=2048 -max_len=65536 -print_final_stats=1 "${inputs[@]}" \
        > "fuzz-$target.log" 2>&1); then
    echo "fuzz: $target FAILED (build-fuzz/fuzz-$target.log)"; tail -n 30 "build-fuzz/fuzz-$target.log"
    status=1
  else
    grep -E "stat::number_of_executed_units|cov:" "build-fuzz/fuzz-$target.log" | tail -n 2
  fi
done
exit $status
