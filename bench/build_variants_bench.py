#!/usr/bin/env python3
"""Build variants side by side: the default build, redundant-edge pruning
(--prune) and pseudo vertices (--pseudo-vertices, section 4.3 of the DGG
paper), and small epsilons: build time, graph size and field accuracy
against the exact fields of ../shared/truth, every variant in the same run on
the same threads.

  bench/build_variants_bench.py --runs spot:1e-3,camelhead:1e-3,blade_aniso:1e-2 \
      --variants default,prune,pseudo

Prints a Markdown table (for bench/measurements.md, which BENCHMARKS.md
carries) and the rows as JSON on stderr.
"""
import argparse
import glob
import json
import os
import subprocess
import sys
import tempfile

import numpy as np

from shared_data import SHARED

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.join(ROOT, "build", "bin", "geodesicd")


def run_json(*args):
    r = subprocess.run([BIN, *args, "--json"], capture_output=True, text=True, check=True)
    return json.loads(r.stdout)


def field_errors(mesh, graph, name, workdir):
    """Mean and max relative error (over vertices with a finite exact value) and the most
    negative one, over every truth source of the mesh."""
    rel = []
    for truth in sorted(glob.glob(os.path.join(SHARED, "truth", name + ".exact.s*.f64"))):
        source = truth.rsplit(".s", 1)[1][:-4]
        out = os.path.join(workdir, "field.f64")
        run_json("field", "--mesh", mesh, "--graph", graph, "--source", "v:" + source,
                 "--out", out)
        exact, got = np.fromfile(truth, "<f8"), np.fromfile(out, "<f8")
        ok = np.isfinite(exact) & (exact > 0)
        rel.append((got[ok] - exact[ok]) / exact[ok])
    rel = np.concatenate(rel)
    return float(rel.mean()), float(rel.max()), float(rel.min())


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", default="blade_aniso:1e-2,blade_aniso:1e-3,spot:1e-4")
    ap.add_argument("--variants", default="default,pseudo",
                    help="comma-separated: default, prune, pseudo")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    workdir = tempfile.mkdtemp(prefix="pseudo_bench_")
    rows = []
    for run in args.runs.split(","):
        name, eps = run.split(":")
        mesh = glob.glob(os.path.join(SHARED, "meshes", name + ".*"))[0]
        for variant in args.variants.split(","):
            graph = os.path.join(workdir, "g.dgg")
            flags = {"default": [], "prune": ["--prune"], "pseudo": ["--pseudo-vertices"]}[variant]
            b = run_json("build", mesh, "--eps", eps, "--out", graph, "--threads",
                         str(args.threads), *flags)
            mean, worst, below = field_errors(mesh, graph, name, workdir)
            row = {"mesh": name, "eps": float(eps), "variant": variant, "build": b,
                   "mean_err_eps": mean / float(eps), "max_err_eps": worst / float(eps),
                   "most_below": below}
            print(json.dumps(row), file=sys.stderr)
            rows.append(row)
    print("| mesh | ε | variant | build 1t (s) | candidates (s) | pruning (s) | nodes | avg degree "
          "| file (MB) | mean / max err (ε) | most below exact |")
    print("|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        b = r["build"]
        print("| %s | %g | %s | %.2f | %.2f | %.2f | %d | %.1f | %.1f | %.3f / %.3f | %.1e |" % (
            r["mesh"], r["eps"], r["variant"], b["build_seconds"], b["candidate_seconds"],
            b["pruning_seconds"], b["nodes"], b["average_degree"], b["file_bytes"] / 1e6,
            r["mean_err_eps"], r["max_err_eps"], r["most_below"]))


if __name__ == "__main__":
    main()
