#!/usr/bin/env python3
"""How far a check from a few seeded sources can be trusted (certified
graphs, core/query/certified_graph.h).

For each mesh, bound B and build scale k: builds the graph at k*B, checks
it (`geodesicd check`, our exact engine, every vertex a target) from M
seeded random vertex sources, and measures it against the independent
exact truth (../shared/truth, CGAL's fields from three sources). From the
per-source maxima it reports, in units of B:

  max8 / max16   the maxima over the first 8 and 16 sources (what a
                 certificate with --sources 8 or 16 and this seed sees)
  low8 / low16   the smallest maximum of any disjoint group of 8 (16)
                 among the M sources: the most a certification of that
                 size could have underestimated by luck of the draw
  maxM           the maximum over all M sources
  truth          the maximum over the truth sources' fields
  ratio8/16      maxM / low8 and maxM / low16: the factor a certificate
                 of that many sources must keep in hand

  bench/certify_margins.py [--meshes spot,...] [--bounds 1e-2,1e-3]
      [--scales 0.6] [--sources 128] [--seed 1] [--threads 2]
      [--bin build/bin] [--shared ../shared] [--out rows.jsonl]

With --certified, it checks the margins chosen instead: for each mesh and
bound, `geodesicd build --max-error B` (its default sources and seed), then
the published graph against the truth fields and from M sources of
another seed (--seed), none of which the certificate saw:

  bench/certify_margins.py --certified [--meshes ...] [--bounds ...]
      [--sources 64] [--seed 1000]

Standard library only.
"""
import argparse
import glob
import json
import math
import os
import re
import subprocess
import tempfile

from truth_meshes import mesh_path, read_f64
from shared_data import SHARED

HERE = os.path.dirname(os.path.abspath(__file__))


def run_json(cmd):
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode not in (0, 1) or not done.stdout.strip():
        raise SystemExit(f"{' '.join(cmd)} failed: {done.stderr}")
    return json.loads(done.stdout)


def truth_max(args, name, mesh, graph, work):
    """Largest relative error of the graph's fields against CGAL's."""
    worst = 0.0
    for truth in sorted(glob.glob(os.path.join(args.shared, "truth", f"{name}.exact.s*.f64"))):
        source = re.search(r"\.s(\d+)\.f64$", truth).group(1)
        out = os.path.join(work, "field.f64")
        subprocess.run([f"{args.bin}/geodesicd", "field", "--mesh", mesh, "--graph", graph,
                        "--source", f"v:{source}", "--out", out], check=True, capture_output=True)
        for approx, exact in zip(read_f64(out), read_f64(truth)):
            if math.isfinite(exact) and exact > 0:
                worst = max(worst, (approx - exact) / exact)
    return worst


def group_low(maxima, size):
    groups = [maxima[i:i + size] for i in range(0, len(maxima) - size + 1, size)]
    return min(max(g) for g in groups)


def measure(args, name, bound, scale, work):
    mesh = mesh_path(args.shared, name)
    graph = os.path.join(work, f"{name}.dgg")
    eps = scale * bound
    built = run_json([f"{args.bin}/geodesicd", "build", mesh, "--eps", repr(eps), "--threads",
                      str(args.threads), "--out", graph, "--json"])
    checked = run_json([f"{args.bin}/geodesicd", "check", "--mesh", mesh, "--graph", graph,
                        "--sources", str(args.sources), "--seed", str(args.seed), "--threads",
                        str(args.threads), "--json"])
    # Per source, in units of the bound.
    maxima = [row["max_error_eps"] * eps / bound for row in checked["sources"]]
    truth = truth_max(args, name, mesh, graph, work) / bound
    os.remove(graph)
    max_m = max(maxima)
    row = {
        "mesh": name, "bound": bound, "scale": scale, "sources": len(maxima), "seed": args.seed,
        "found_degree": built["found_degree"], "build_seconds": built["build_seconds"],
        "check_seconds": checked["seconds"], "sound": checked["sound"],
        "mean": checked["mean_error_eps"] * eps / bound,
        "max8": max(maxima[:8]), "max16": max(maxima[:16]),
        "low8": group_low(maxima, 8), "low16": group_low(maxima, 16),
        "maxM": max_m, "truth": truth, "per_source": maxima,
    }
    row["ratio8"] = max_m / row["low8"]
    row["ratio16"] = max_m / row["low16"]
    return row


def certified(args, name, bound, work):
    mesh = mesh_path(args.shared, name)
    graph = os.path.join(work, f"{name}.dgg")
    built = run_json([f"{args.bin}/geodesicd", "build", mesh, "--max-error", repr(bound),
                      "--threads", str(args.threads), "--out", graph, "--json"])
    cert = built["certificate"]
    checked = run_json([f"{args.bin}/geodesicd", "check", "--mesh", mesh, "--graph", graph,
                        "--sources", str(args.sources), "--seed", str(args.seed), "--threads",
                        str(args.threads), "--json"])
    unseen = checked["max_error_eps"] * cert["epsilon"] / bound
    truth = truth_max(args, name, mesh, graph, work) / bound
    os.remove(graph)
    return {"mesh": name, "bound": bound, "certificate": cert,
            "found_degree": built["found_degree"], "build_seconds": built["build_seconds"],
            "unseen_sources": args.sources, "unseen_seed": args.seed, "unseen_max": unseen,
            "truth": truth}


def main_certified(args, out):
    print("| mesh | bound | eps (B) | builds | certified max (B) | mean (B) | unseen max (B) "
          "| truth max (B) | found degree |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as work:
        for bound in (float(b) for b in args.bounds.split(",")):
            for name in args.meshes.split(","):
                r = certified(args, name, bound, work)
                c = r["certificate"]
                print(f"| {name} | {bound:g} | {c['epsilon'] / bound:.3f} | {c['builds']} "
                      f"| {c['measured_max_error'] / bound:.3f} "
                      f"| {c['measured_mean_error'] / bound:.3f} | {r['unseen_max']:.3f} "
                      f"| {r['truth']:.3f} | {r['found_degree']:.1f} |", flush=True)
                if out:
                    out.write(json.dumps(r) + "\n")
                    out.flush()


def main():
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--meshes", default="eight,spot,blade_aniso,camelhead,fertility,armadillo")
    p.add_argument("--bounds", default="1e-2,1e-3")
    p.add_argument("--scales", default="0.6")
    p.add_argument("--sources", type=int, default=128)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--bin", default=os.path.join(HERE, "..", "build", "bin"))
    p.add_argument("--shared", default=SHARED)
    p.add_argument("--out")
    p.add_argument("--certified", action="store_true")
    args = p.parse_args()
    out = open(args.out, "a") if args.out else None
    if args.certified:
        return main_certified(args, out)
    print("| mesh | bound | built at | M | mean | max8 | max16 | low8 | low16 | maxM | truth "
          "| ratio8 | ratio16 |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as work:
        for bound in (float(b) for b in args.bounds.split(",")):
            for name in args.meshes.split(","):
                for scale in (float(k) for k in args.scales.split(",")):
                    r = measure(args, name, bound, scale, work)
                    print(f"| {name} | {bound:g} | {scale:g} B | {r['sources']} | {r['mean']:.3f} "
                          f"| {r['max8']:.3f} | {r['max16']:.3f} | {r['low8']:.3f} "
                          f"| {r['low16']:.3f} | {r['maxM']:.3f} | {r['truth']:.3f} "
                          f"| {r['ratio8']:.2f} | {r['ratio16']:.2f} |"
                          + ("" if r["sound"] else " UNSOUND"), flush=True)
                    if out:
                        out.write(json.dumps(r) + "\n")
                        out.flush()


if __name__ == "__main__":
    main()
