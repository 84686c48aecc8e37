#!/usr/bin/env python3
"""Two builds of `geodesicd build` side by side: each mesh built by both
binaries in alternating rounds, with the phase times of each and a check
that the two graph files are the same bytes.

  bench/build_ab_bench.py --before OLD/geodesicd --after build/bin/geodesicd \\
      [--meshes armadillo,bunny] [--eps 1e-3] [--threads 2] [--rounds 5]

Prints a Markdown table for bench/measurements.md: median build, candidate
and fan seconds of each binary and the after/before ratios of the medians.
"""
import filecmp
import json
import os
import statistics
import subprocess
import sys
import tempfile

from ab_args import before_after_parser
from truth_meshes import mesh_path
from shared_data import SHARED

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PHASES = ["build_seconds", "candidate_seconds", "fan_seconds"]


def build(binary, mesh, eps, threads, out):
    result = subprocess.run([binary, "build", mesh, "--eps", str(eps), "--threads", str(threads),
                             "--quiet", "--json", "--out", out], capture_output=True, text=True)
    if result.returncode != 0:
        sys.exit(f"{binary} build {mesh} failed:\n{result.stderr[-2000:]}")
    stats = json.loads(result.stdout)
    for key in PHASES:
        if not stats.get(key, 0) > 0:
            sys.exit(f"{binary} build {mesh}: no positive {key} in its JSON")
    return stats


def main():
    parser = before_after_parser(__doc__, rounds=5)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()

    print("| mesh | eps | threads | before build / candidates / fans (s) "
          "| after build / candidates / fans (s) | after / before: build, fans | same bytes |")
    print("|---|---:|---:|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.meshes.split(","):
            mesh = mesh_path(SHARED, name)
            runs = {"before": [], "after": []}
            files = {side: os.path.join(tmp, side + ".dgg") for side in runs}
            for _ in range(args.rounds):
                for side in runs:
                    binary = args.before if side == "before" else args.after
                    runs[side].append(build(binary, mesh, args.eps, args.threads, files[side]))
            med = {side: [statistics.median(r[k] for r in runs[side]) for k in PHASES]
                   for side in runs}
            same = filecmp.cmp(files["before"], files["after"], shallow=False)
            b, a = med["before"], med["after"]
            print(f"| {name} | {args.eps:g} | {args.threads} | {b[0]:.2f} / {b[1]:.2f} / {b[2]:.3f} "
                  f"| {a[0]:.2f} / {a[1]:.2f} / {a[2]:.3f} | {a[0] / b[0]:.2f}x, {a[2] / b[2]:.2f}x "
                  f"| {'yes' if same else 'no'} |", flush=True)


if __name__ == "__main__":
    main()
