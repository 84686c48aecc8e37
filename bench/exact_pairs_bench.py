#!/usr/bin/env python3
"""Exact pairs against the independent solver's: the shared point-to-point
pairs of each mesh answered by `geodesicd distance --exact` (a window
propagation bounded by the graph's answer), beside the same pairs on the
graph alone, the same pairs again with exact landmarks (`--exact-landmarks`:
exact fields from a few landmarks computed once, whose bounds narrow each
pair's region) and one whole exact field from the first pair's first point,
all in the same run, one thread.

  bench/exact_pairs_bench.py [--meshes armadillo,bunny] [--eps 1e-3] [--pairs 200]
                             [--exact-landmarks 128]

Prints a Markdown table for BENCHMARKS.md (bench/measurements.md, "Exact
pairs") and the rows as JSON on stderr.
"""
import argparse
import json
import os
import platform
import re
import subprocess
import sys
import tempfile

import numpy as np

from shared_data import SHARED

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.environ.get("GEODESIC_BIN", os.path.join(ROOT, "build", "bin"))
MESHES = {"armadillo": "armadillo.obj", "bunny": "bunny.ply", "fertility": "fertility.off",
          "camelhead": "camelhead.off"}


def run_json(args, stderr=None):
    out = subprocess.run(["taskset", "-c", "0"] + args, capture_output=True, text=True, check=True)
    if stderr is not None:
        stderr.append(out.stderr)
    return json.loads(out.stdout)


def summary(runs, exact):
    """p50/p90 time and windows of exact answers, and their largest relative
    difference from the solver's on pairs both sides reach."""
    assert runs and all(r["exact"] for r in runs), "an answer is not marked exact"
    got = np.array([r["distance"] if r["distance"] is not None else np.inf for r in runs])
    finite = np.isfinite(exact) & (exact > 0)
    assert finite.sum() > 0 and np.isfinite(got[finite]).all(), "no comparable pair"
    secs = np.array([r["seconds"] for r in runs])
    return {"p50_ms": 1e3 * np.percentile(secs, 50), "p90_ms": 1e3 * np.percentile(secs, 90),
            "windows_p50": float(np.percentile([r["windows"] for r in runs], 50)),
            "max_rel_diff": float((np.abs(got[finite] - exact[finite]) / exact[finite]).max())}


def measure(name, eps, count, landmarks, work):
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
    plain = summary(run_json(base + ["--exact"]), exact)
    with_paths = summary(run_json(base + ["--exact", "--path"]), exact)
    log = []
    marked = summary(run_json(base + ["--exact", "--exact-landmarks", str(landmarks)], log), exact)
    prepared = re.search(r"exact landmarks: \d+ fields in ([0-9.]+) s", log[0])
    assert prepared, f"no landmark time in: {log[0]!r}"
    field = run_json([f"{BIN}/geodesicd", "exact", "--mesh", mesh, "--source",
                      lines[0].split()[0], "--out", os.path.join(work, "field.f64"), "--json"])
    graph_secs = np.array([r["seconds"] for r in on_graph])
    return {
        "mesh": name, "vertices": build["vertices"] if "vertices" in build else None,
        "eps": eps, "pairs": len(lines),
        "exact_p50_ms": plain["p50_ms"], "exact_p90_ms": plain["p90_ms"],
        "exact_path_p50_ms": with_paths["p50_ms"],
        "graph_p50_ms": 1e3 * np.percentile(graph_secs, 50),
        "field_exact_ms": 1e3 * field["solve_seconds"],
        "windows_p50": plain["windows_p50"],
        "max_rel_diff": max(plain["max_rel_diff"], with_paths["max_rel_diff"]),
        "landmarks": landmarks, "landmarks_seconds": float(prepared.group(1)),
        "landmark_p50_ms": marked["p50_ms"], "landmark_p90_ms": marked["p90_ms"],
        "landmark_windows_p50": marked["windows_p50"],
        "landmark_max_rel_diff": marked["max_rel_diff"],
    }


def markdown(rows, args):
    out = [f"`bench/exact_pairs_bench.py --meshes {args.meshes} --eps {args.eps} "
           f"--pairs {args.pairs} --exact-landmarks {args.exact_landmarks}`, one thread (taskset -c 0), {platform.node() or 'this machine'}, "
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
    out += ["", "With exact landmarks (computed once per mesh, before the pairs, on the same one "
            "thread):", "",
            "| mesh | landmarks | computed in (s) | exact p50 (ms) | exact p90 (ms) | "
            "p50 vs without | windows p50 | max rel. diff vs solver | pairs that repay it |",
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        saved = r["exact_p50_ms"] - r["landmark_p50_ms"]
        repay = f"{1e3 * r['landmarks_seconds'] / saved:.0f}" if saved > 0 else "never"
        out.append(f"| {r['mesh']} | {r['landmarks']} | {r['landmarks_seconds']:.1f} | "
                   f"{r['landmark_p50_ms']:.2f} | {r['landmark_p90_ms']:.2f} | "
                   f"{r['exact_p50_ms'] / r['landmark_p50_ms']:.1f}x faster | "
                   f"{r['landmark_windows_p50']:.0f} | {r['landmark_max_rel_diff']:.1e} | "
                   f"{repay} |")
    return "\n".join(out) + "\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--meshes", default="armadillo,bunny")
    ap.add_argument("--eps", type=float, default=1e-3)
    ap.add_argument("--pairs", type=int, default=200)
    ap.add_argument("--exact-landmarks", type=int, default=128)
    args = ap.parse_args()
    work = tempfile.mkdtemp(prefix="exact_pairs_")
    rows = []
    for name in args.meshes.split(","):
        rows.append(measure(name, args.eps, args.pairs, args.exact_landmarks, work))
        print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    sys.stdout.write(markdown(rows, args))


if __name__ == "__main__":
    main()
