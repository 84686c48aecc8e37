#!/usr/bin/env python3
"""Exact pairs against the independent solver's: the shared point-to-point
pairs of each mesh answered by `geodesicd distance --exact` (a window
propagation bounded by the graph's answer), beside the same pairs on the
graph alone and one whole exact field from the first pair's first point, all
in the same run, one thread.

  bench/exact_pairs_bench.py [--meshes armadillo,bunny] [--eps 1e-3] [--pairs 200]

Prints a Markdown table for BENCHMARKS.md (bench/measurements.md, "Exact
pairs") and the rows as JSON on stderr.
"""
import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SHARED = os.environ.get("GEODESIC_SHARED_DIR", os.path.join(os.path.dirname(ROOT), "shared"))
BIN = os.environ.get("GEODESIC_BIN", os.path.join(ROOT, "build", "bin"))
MESHES = {"armadillo": "armadillo.obj", "bunny": "bunny.ply", "fertility": "fertility.off",
          "camelhead": "camelhead.off"}


def run_json(args):
    out = subprocess.run(["taskset", "-c", "0"] + args, capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


def measure(name, eps, count, work):
    mesh = os.path.join(SHARED, "meshes", MESHES[name])
    truth = os.path.join(SHARED, "truth")
    lines = [l for l in open(os.path.join(truth, f"{name}.p2p.pairs")).read().split("\n")
             if l.strip()][:count]
    exact = np.array([float(x) for x in
                      open(os.path.join(truth, f"{name}.p2p.exact")).read().split()])[:len(lines)]
    pairs = os.path.join(work, f"{name}.pairs")
    with open(pairs, "w") as f:
        f.write("\n".join(lines) + "\n")
    graph = os.path.join(work, f"{name}.dgg")
    build = run_json([f"{BIN}/geodesicd", "build", mesh, "--eps", str(eps), "--out", graph,
                      "--threads", "1", "--json"])
    base = [f"{BIN}/geodesicd", "distance", "--mesh", mesh, "--graph", graph, "--pairs", pairs,
            "--json"]
    on_graph = run_json(base)
    exact_runs = run_json(base + ["--exact"])
    with_paths = run_json(base + ["--exact", "--path"])
    field = run_json([f"{BIN}/geodesicd", "exact", "--mesh", mesh, "--source",
                      lines[0].split()[0], "--out", os.path.join(work, "field.f64"), "--json"])
    got = np.array([r["distance"] if r["distance"] is not None else np.inf for r in exact_runs])
    assert all(r["exact"] for r in exact_runs), "an answer is not marked exact"
    finite = np.isfinite(exact) & (exact > 0)
    assert finite.sum() > 0 and np.isfinite(got[finite]).all(), "no comparable pair"
    rel = np.abs(got[finite] - exact[finite]) / exact[finite]
    secs = np.array([r["seconds"] for r in exact_runs])
    graph_secs = np.array([r["seconds"] for r in on_graph])
    path_secs = np.array([r["seconds"] for r in with_paths])
    return {
        "mesh": name, "vertices": build["vertices"] if "vertices" in build else None,
        "eps": eps, "pairs": len(lines),
        "exact_p50_ms": 1e3 * np.percentile(secs, 50), "exact_p90_ms": 1e3 * np.percentile(secs, 90),
        "exact_path_p50_ms": 1e3 * np.percentile(path_secs, 50),
        "graph_p50_ms": 1e3 * np.percentile(graph_secs, 50),
        "field_exact_ms": 1e3 * field["solve_seconds"],
        "windows_p50": float(np.percentile([r["windows"] for r in exact_runs], 50)),
        "max_rel_diff": float(rel.max()),
    }


def markdown(rows, args):
    out = [f"`bench/exact_pairs_bench.py --meshes {args.meshes} --eps {args.eps} "
           f"--pairs {args.pairs}`, one thread (taskset -c 0), {platform.node() or 'this machine'}, "
           f"{os.cpu_count()} cores; the shared pairs in file order (face points, a same-face, a "
           "corner and an edge point per first point).", "",
           "| mesh | ε | pairs | exact p50 (ms) | exact p90 (ms) | with path p50 (ms) | graph p50 (ms) "
           "| one exact field (ms) | field / exact pair | windows p50 | max rel. diff vs solver |",
           "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        out.append(f"| {r['mesh']} | {r['eps']:g} | {r['pairs']} | {r['exact_p50_ms']:.2f} | "
                   f"{r['exact_p90_ms']:.2f} | {r['exact_path_p50_ms']:.2f} | "
                   f"{r['graph_p50_ms']:.3f} | {r['field_exact_ms']:.0f} | "
                   f"{r['field_exact_ms'] / r['exact_p50_ms']:.0f}x | {r['windows_p50']:.0f} | "
                   f"{r['max_rel_diff']:.1e} |")
    return "\n".join(out) + "\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--meshes", default="armadillo,bunny")
    ap.add_argument("--eps", type=float, default=1e-3)
    ap.add_argument("--pairs", type=int, default=200)
    args = ap.parse_args()
    work = tempfile.mkdtemp(prefix="exact_pairs_")
    rows = []
    for name in args.meshes.split(","):
        rows.append(measure(name, args.eps, args.pairs, work))
        print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    sys.stdout.write(markdown(rows, args))


if __name__ == "__main__":
    main()
