#!/usr/bin/env python3
"""What a hard epsilon bound costs (#26): graphs built at a fraction of the
epsilon a user asks for, their errors measured against that epsilon.

For each mesh, target epsilon E and scale k, builds the graph at k*E and
measures against the exact truth (../shared/truth: fields from three
sources, and the exact point-to-point pairs where the mesh has them) the
mean and maximum relative error in units of E, beside the found degree
(edges per vertex as found, the size measure of the issue) and the build
time. k = 1 is today's graph; the smallest k whose maxima stay <= 1 on
every mesh is what "max <= epsilon" would cost.

  bench/epsilon_tradeoff.py [--meshes eight,spot,...] [--eps 1e-2,1e-3]
      [--scales 1,0.8,0.7] [--threads 2] [--bin build/bin] [--shared ../shared]
      [--out rows.jsonl]

Prints one markdown row per (mesh, E, k) as it goes; --out keeps them as
JSON lines. Standard library only.
"""
import argparse
import glob
import json
import math
import os
import re
import subprocess
import tempfile

from truth_meshes import DEFAULT_MESHES, mesh_path, read_f64
from shared_data import SHARED

HERE = os.path.dirname(os.path.abspath(__file__))


def run_json(cmd):
    done = subprocess.run(cmd, check=True, capture_output=True, text=True)
    return json.loads(done.stdout)


class Errors:
    """Relative errors (approximate - exact) / exact, in units of a target eps."""

    def __init__(self, eps):
        self.eps, self.n, self.total, self.max, self.below = eps, 0, 0.0, 0.0, 0

    def add(self, approx, exact):
        if not (math.isfinite(exact) and exact > 0):
            return
        e = (approx - exact) / exact / self.eps
        if e < -1e-9:  # a graph distance under the exact one: a missed geodesic
            self.below += 1
        self.n += 1
        self.total += abs(e)
        self.max = max(self.max, abs(e))

    def mean(self):
        return self.total / self.n if self.n else float("nan")


def measure(args, name, target, scale, work):
    mesh = mesh_path(args.shared, name)
    graph = os.path.join(work, f"{name}.dgg")
    built = run_json([f"{args.bin}/geodesicd", "build", mesh, "--eps", repr(scale * target),
                      "--threads", str(args.threads), "--out", graph, "--json"])
    fields = Errors(target)
    for truth in sorted(glob.glob(os.path.join(args.shared, "truth", f"{name}.exact.s*.f64"))):
        source = re.search(r"\.s(\d+)\.f64$", truth).group(1)
        out = os.path.join(work, "field.f64")
        subprocess.run([f"{args.bin}/geodesicd", "field", "--mesh", mesh, "--graph", graph,
                        "--source", f"v:{source}", "--out", out], check=True, capture_output=True)
        for approx, exact in zip(read_f64(out), read_f64(truth)):
            fields.add(approx, exact)
    pairs = Errors(target)
    pair_file = os.path.join(args.shared, "truth", f"{name}.p2p.pairs")
    if os.path.exists(pair_file):
        answers = run_json([f"{args.bin}/geodesicd", "distance", "--mesh", mesh, "--graph", graph,
                            "--pairs", pair_file, "--json"])
        exact = [float(x) for x in open(os.path.join(args.shared, "truth", f"{name}.p2p.exact"))
                 .read().split()]
        for answer, d in zip(answers, exact):
            pairs.add(answer["distance"] if answer["distance"] is not None else math.inf, d)
    os.remove(graph)
    return {
        "mesh": name, "eps": target, "scale": scale, "built_eps": scale * target,
        "found_degree": built["found_degree"], "average_degree": built["average_degree"],
        "build_seconds": built["build_seconds"], "threads": args.threads,
        "field_values": fields.n, "field_mean_eps": fields.mean(), "field_max_eps": fields.max,
        "field_below_exact": fields.below, "pairs": pairs.n, "pair_mean_eps": pairs.mean(),
        "pair_max_eps": pairs.max, "pair_below_exact": pairs.below,
    }


def main():
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--meshes", default=DEFAULT_MESHES)
    p.add_argument("--eps", default="1e-2,1e-3")
    p.add_argument("--scales", default="1,0.8,0.7")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--bin", default=os.path.join(HERE, "..", "build", "bin"))
    p.add_argument("--shared", default=SHARED)
    p.add_argument("--out")
    args = p.parse_args()
    out = open(args.out, "a") if args.out else None
    print("| mesh | ε | built at | found (average) degree | field mean (ε) | field max (ε) "
          "| pair max (ε) | build s |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as work:
        for target in (float(e) for e in args.eps.split(",")):
            for name in args.meshes.split(","):
                for scale in (float(k) for k in args.scales.split(",")):
                    row = measure(args, name, target, scale, work)
                    pair_max = f"{row['pair_max_eps']:.3f}" if row["pairs"] else "-"
                    print(f"| {name} | {target:g} | {scale:g} ε | {row['found_degree']:.2f} "
                          f"({row['average_degree']:.2f}) "
                          f"| {row['field_mean_eps']:.3f} | {row['field_max_eps']:.3f} "
                          f"| {pair_max} | {row['build_seconds']:.2f} |", flush=True)
                    if row["field_below_exact"] or row["pair_below_exact"]:
                        print(f"  {name}: {row['field_below_exact']} field values and "
                              f"{row['pair_below_exact']} pairs below exact", flush=True)
                    if out:
                        out.write(json.dumps(row) + "\n")
                        out.flush()


if __name__ == "__main__":
    main()
