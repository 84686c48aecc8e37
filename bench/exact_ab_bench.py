#!/usr/bin/env python3
"""Two builds of `geodesicd exact` side by side: one whole exact field per
mesh from vertex 0, the two binaries alternating on one pinned CPU, a few
rounds each, with the fields compared value by value.

  bench/exact_ab_bench.py --before OLD/geodesicd --after build/bin/geodesicd \\
      [--meshes eight,spot,...] [--rounds 3] [--cpu 1]

Prints a Markdown table for bench/measurements.md: median solve seconds and
windows of each, their ratios, and the largest relative difference between
the two fields (and, where ../shared/truth has the field from vertex 0,
between the after field and that exact truth).
"""
import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import json

import numpy as np

from shared_data import SHARED

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MESHES = ["eight", "spot", "blade_aniso", "camelhead", "fertility", "bunny", "armadillo", "igea"]


def mesh_file(name):
    for f in sorted(os.listdir(os.path.join(SHARED, "meshes"))):
        if os.path.splitext(f)[0] == name:
            return os.path.join(SHARED, "meshes", f)
    sys.exit(f"no mesh named {name} in {SHARED}/meshes")


def solve(binary, mesh, cpu, out):
    result = subprocess.run(["taskset", "-c", str(cpu), binary, "exact", "--mesh", mesh,
                             "--source", "v:0", "--json", "--out", out],
                            capture_output=True, text=True)
    if result.returncode != 0:
        sys.exit(f"{binary} exact on {mesh} failed:\n{result.stderr[-2000:]}")
    return json.loads(result.stdout)


def largest_difference(a, b):
    both = np.isfinite(a) & np.isfinite(b) & (a > 0)
    if not both.any():
        sys.exit("no vertex where both fields are finite and positive")
    if (np.isfinite(a) != np.isfinite(b)).any():
        return float("inf")
    return float(np.max(np.abs(a[both] - b[both]) / a[both]))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--before", required=True)
    parser.add_argument("--after", required=True)
    parser.add_argument("--meshes", default=",".join(MESHES))
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--cpu", type=int, default=1)
    args = parser.parse_args()
    print("| mesh | V | before (s) | after (s) | before / after | windows before | windows after "
          "| windows before / after | before vs after, max rel. diff | after vs truth |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as work:
        for name in args.meshes.split(","):
            mesh = mesh_file(name)
            runs = {"before": [], "after": []}
            for _ in range(args.rounds):
                for side in ("before", "after"):
                    binary = getattr(args, side)
                    runs[side].append(solve(binary, mesh, args.cpu, f"{work}/{side}.f64"))
            before = np.fromfile(f"{work}/before.f64")
            after = np.fromfile(f"{work}/after.f64")
            diff = largest_difference(before, after)
            truth_file = os.path.join(SHARED, "truth", f"{name}.exact.s0.f64")
            truth = (f"{largest_difference(np.fromfile(truth_file), after):.2g}"
                     if os.path.exists(truth_file) else "-")
            t = {s: statistics.median(r["solve_seconds"] for r in runs[s]) for s in runs}
            w = {s: runs[s][0]["windows_created"] for s in runs}
            print(f"| {name} | {runs['after'][0]['vertices']:,} | {t['before']:.3g} | "
                  f"{t['after']:.3g} | {t['before'] / t['after']:.2f}x | {w['before']:,} | "
                  f"{w['after']:,} | {w['before'] / w['after']:.2f}x | {diff:.2g} | {truth} |",
                  flush=True)


if __name__ == "__main__":
    main()
