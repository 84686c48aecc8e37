#!/usr/bin/env python3
"""Two builds of `geodesicd distance` side by side on random face-point pairs:
both binaries run at the same time, one per CPU, swapping CPUs every round,
so that the host's swings (a third within an hour on the 2-core VM) hit
both alike; their ratio is taken round by round.

  bench/pairs_ab_bench.py --before OLD/geodesicd --after build/bin/geodesicd \\
      [--meshes armadillo,bunny] [--eps 0.001] [--pairs 2000] [--rounds 6]

The graphs are built once by --after (into a temporary directory, or read
from --graph-dir/<mesh>-<eps>.dgg when there). Prints a Markdown table for
bench/measurements.md: each binary's p50 per pair (median over rounds), the
after/before ratio (median, least and largest over rounds), the median
relaxed edges of each, and the largest relative difference between the two
binaries' distances.
"""
import json
import os
import random
import statistics
import subprocess
import sys
import tempfile

import numpy as np

from ab_args import before_after_parser
from daemon_bench import random_pairs
from exact_ab_bench import mesh_file


def run(args, what):
    result = subprocess.run(args, capture_output=True, text=True)
    if result.returncode != 0:
        sys.exit(f"{what} failed:\n{result.stderr[-2000:]}")
    return result.stdout


def write_pairs(binary, mesh, count, seed, path):
    faces = json.loads(run([binary, "info", mesh, "--json"], f"info {mesh}"))["faces"]
    pairs = random_pairs(0, faces, count, True, random.Random(seed))
    with open(path, "w") as out:
        out.write("\n".join(pairs) + "\n")


def start(binary, cpu, mesh, graph, pairs):
    return subprocess.Popen(["taskset", "-c", str(cpu), binary, "distance", "--mesh", mesh,
                             "--graph", graph, "--pairs", pairs, "--json"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def finish(process, binary):
    out, err = process.communicate()
    if process.returncode != 0:
        sys.exit(f"{binary} distance failed:\n{err[-2000:]}")
    rows = json.loads(out)
    if not rows:
        sys.exit(f"{binary} distance answered no pairs")
    distances = np.array([r["distance"] for r in rows])
    if not np.isfinite(distances).all():
        sys.exit(f"{binary} distance left pairs unreached on a connected mesh")
    return (1e3 * float(np.percentile([r["seconds"] for r in rows], 50)),
            statistics.median(r["relaxed"] for r in rows), distances)


def main():
    parser = before_after_parser(__doc__, rounds=6)
    parser.add_argument("--pairs", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--graph-dir", default="")
    args = parser.parse_args()

    print("| mesh | ε | pairs | before p50 (ms) | after p50 (ms) | after / before: median "
          "(least, largest) | relaxed before | relaxed after | max rel. diff |")
    print("|---|---:|---:|---:|---:|---|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as work:
        for name in args.meshes.split(","):
            mesh = mesh_file(name)
            graph = os.path.join(args.graph_dir or work, f"{name}-{args.eps:g}.dgg")
            if not os.path.exists(graph):
                run([args.after, "build", mesh, "--eps", str(args.eps), "--out", graph],
                    f"build {name}")
            pairs = os.path.join(work, f"{name}.pairs")
            write_pairs(args.after, mesh, args.pairs, args.seed, pairs)
            before, after, ratios = [], [], []
            for r in range(args.rounds):
                cpus = (0, 1) if r % 2 == 0 else (1, 0)
                pb = start(args.before, cpus[0], mesh, graph, pairs)
                pa = start(args.after, cpus[1], mesh, graph, pairs)
                b, a = finish(pb, args.before), finish(pa, args.after)
                before.append(b)
                after.append(a)
                ratios.append(a[0] / b[0])
            diff = float(np.max(np.abs(after[-1][2] - before[-1][2]) / before[-1][2]))
            print(f"| {name} | {args.eps:g} | {args.pairs} "
                  f"| {statistics.median(x[0] for x in before):.3f} "
                  f"| {statistics.median(x[0] for x in after):.3f} "
                  f"| {statistics.median(ratios):.3f} ({min(ratios):.3f}, {max(ratios):.3f}) "
                  f"| {before[-1][1]:.0f} | {after[-1][1]:.0f} | {diff:.2g} |", flush=True)


if __name__ == "__main__":
    main()
