#!/usr/bin/python3
"""End-to-end benchmark driver: regenerates bench/results.csv and BENCHMARKS.md.

For each mesh and epsilon, in one run on this machine: DGG build time per
phase with 1 and 2 threads, peak memory, degree and bytes; field solve time
(DGG-tailored label-correcting and plain Dijkstra on the same graph) and its
accuracy against the exact fields in ../shared/truth; point-to-point latency
percentiles and accuracy against the exact pairs; path time; and our exact
engine's field time. CGAL's heat-method accuracy is read from the shared
truth directory (computed by CGAL 5.5 there); its timings are quoted from the
truth README, since CGAL is not built here.

Usage: bench/run_benchmarks.py [--quick] [--meshes a,b] [--eps 1e-2,1e-3]
"""
import argparse
import csv
import json
import os
import platform
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SHARED = os.path.join(os.path.dirname(ROOT), "shared")
BIN = os.path.join(ROOT, "build", "bin")
MESHES = {
    "eight": "eight.off", "spot": "spot.obj", "blade_aniso": "blade_aniso.off",
    "camelhead": "camelhead.off", "fertility": "fertility.off", "bunny": "bunny.ply",
    "armadillo": "armadillo.obj",
}


def run(args):
    out = subprocess.run(args, check=True, capture_output=True, text=True)
    return out.stdout


def run_json(args):
    return json.loads(run(args))


def rel_errors(got, want):
    mask = np.isfinite(want) & (want > 0)
    e = (got[mask] - want[mask]) / want[mask]
    return np.abs(e).mean(), np.abs(e).max(), e.min()


def truth_sources(name):
    tdir = os.path.join(SHARED, "truth")
    return sorted(int(f.split(".s")[1].split(".")[0]) for f in os.listdir(tdir)
                  if f.startswith(name + ".exact.s"))


def bench_mesh(name, eps_list, rows, quick):
    mesh = os.path.join(SHARED, "meshes", MESHES[name])
    info = run_json([f"{BIN}/geodesicd", "info", mesh, "--json"])
    n = info["vertices"]
    sources = truth_sources(name)
    tdir = os.path.join(SHARED, "truth")
    work = tempfile.mkdtemp()
    # Our exact engine versus the truth, one source.
    ex = run_json([f"{BIN}/geodesicd", "exact", "--mesh", mesh, "--source", f"v:{sources[0]}",
                   "--out", f"{work}/exact.f64", "--json"])
    exact_field = np.fromfile(f"{work}/exact.f64")
    truth0 = np.fromfile(os.path.join(tdir, f"{name}.exact.s{sources[0]}.f64"))
    exact_err = rel_errors(exact_field, truth0)
    heat = [rel_errors(np.fromfile(os.path.join(tdir, f"{name}.heat.s{s}.f64")),
                       np.fromfile(os.path.join(tdir, f"{name}.exact.s{s}.f64")))[0]
            for s in sources]
    heat_idt = [rel_errors(np.fromfile(os.path.join(tdir, f"{name}.heat-idt.s{s}.f64")),
                           np.fromfile(os.path.join(tdir, f"{name}.exact.s{s}.f64")))[0]
                for s in sources]
    for eps in eps_list:
        graph = f"{work}/{name}-{eps}.dgg"
        builds = {}
        for threads in (1, 2):
            builds[threads] = run_json([f"{BIN}/geodesicd", "build", mesh, "--eps", str(eps),
                                        "--out", graph, "--threads", str(threads), "--json"])
        b1, b2 = builds[1], builds[2]
        field_lc, field_dj, errs = [], [], []
        for s in sources:
            lc = run_json([f"{BIN}/geodesicd", "field", "--mesh", mesh, "--graph", graph,
                           "--source", f"v:{s}", "--out", f"{work}/f.f64", "--json"])
            got = np.fromfile(f"{work}/f.f64")
            dj = run_json([f"{BIN}/geodesicd", "field", "--mesh", mesh, "--graph", graph,
                           "--source", f"v:{s}", "--method", "dijkstra", "--json"])
            field_lc.append(lc)
            field_dj.append(dj)
            errs.append(rel_errors(got, np.fromfile(os.path.join(tdir, f"{name}.exact.s{s}.f64"))))
        row = {
            "mesh": name, "vertices": n, "eps": eps,
            "build_s_1t": b1["build_seconds"], "build_s_2t": b2["build_seconds"],
            "candidate_s_1t": b1["candidate_seconds"], "pruning_s_1t": b1["pruning_seconds"],
            "windows_per_source": b1["windows_per_source"],
            "peak_mem_mb": b1["peak_memory_bytes"] / 2**20,
            "avg_degree": b1["average_degree"], "max_degree": b1["max_degree"],
            "candidate_edges": b1["candidate_edges"], "edges": b1["edges"],
            "file_mb": b1["file_bytes"] / 2**20,
            "field_lc_ms": 1e3 * np.median([f["solve_seconds"] for f in field_lc]),
            "field_dijkstra_ms": 1e3 * np.median([f["solve_seconds"] for f in field_dj]),
            "field_ns_per_vertex": np.median([f["ns_per_vertex"] for f in field_lc]),
            "pops_per_vertex": np.median([f["queue_pops_per_vertex"] for f in field_lc]),
            "graph_open_ms": 1e3 * np.median([f["graph_open_seconds"] for f in field_lc]),
            "field_mean_err_eps": np.mean([e[0] for e in errs]) / eps,
            "field_max_err_eps": np.max([e[1] for e in errs]) / eps,
            "field_most_under": np.min([e[2] for e in errs]),
            "exact_field_s": ex["solve_seconds"], "exact_windows_per_vertex": ex["windows_per_vertex"],
            "exact_mean_err": exact_err[0], "exact_max_err": exact_err[1],
            "cgal_heat_mean_err": np.mean(heat), "cgal_heat_idt_mean_err": np.mean(heat_idt),
        }
        pairs = os.path.join(tdir, f"{name}.p2p.pairs")
        if os.path.exists(pairs):
            lines = open(pairs).read().split("\n")
            if quick:
                lines = lines[:50]
            pf = f"{work}/pairs.txt"
            open(pf, "w").write("\n".join(lines))
            exact = np.array([float(x) for x in open(os.path.join(tdir, f"{name}.p2p.exact")).read().split()])[: len([l for l in lines if l.strip()])]
            res = run_json([f"{BIN}/geodesicd", "distance", "--mesh", mesh, "--graph", graph,
                            "--pairs", pf, "--json"])
            lat = np.array([r["seconds"] for r in res])
            dist = np.array([r["distance"] if r["distance"] is not None else np.inf for r in res])
            plain = run_json([f"{BIN}/geodesicd", "distance", "--mesh", mesh, "--graph", graph,
                              "--pairs", pf, "--json", "--no-astar"])
            paths = run_json([f"{BIN}/geodesicd", "distance", "--mesh", mesh, "--graph", graph,
                              "--pairs", pf, "--json", "--path"])
            m = np.isfinite(exact) & (exact > 0)
            e = (dist[m] - exact[m]) / exact[m]
            row.update({
                "p2p_p50_ms": 1e3 * np.percentile(lat, 50), "p2p_p90_ms": 1e3 * np.percentile(lat, 90),
                "p2p_p99_ms": 1e3 * np.percentile(lat, 99),
                "p2p_mean_err_eps": np.abs(e).mean() / eps, "p2p_max_err_eps": np.abs(e).max() / eps,
                "astar_settled": np.mean([r["settled"] for r in res]),
                "dijkstra_settled": np.mean([r["settled"] for r in plain]),
                "path_p50_ms": 1e3 * np.percentile([r["seconds"] for r in paths], 50),
            })
        rows.append(row)
        print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in row.items()}),
              flush=True)


def fmt(v, digits=3):
    if v is None or v == "":
        return "–"
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    return str(v)


def write_markdown(rows, command, seconds):
    cpu = "unknown"
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    out = []
    out.append("# Benchmarks\n")
    out.append(f"Regenerate: `{command}` (took {seconds / 60:.1f} min). Machine: {os.cpu_count()} cores "
               f"({cpu}), {platform.system()} {platform.release()}. Absolute times are noisy "
               "(other work shares the machine); compare ratios measured in the same run.\n")
    out.append("## Graph construction\n")
    out.append("| mesh | V | ε | build 1 thread (s) | build 2 threads (s) | speed-up | candidates (s, 1t) | pruning (s, 1t) | windows / source | avg degree | max degree | candidate → kept edges | file (MB) | peak RSS (MB) |")
    out.append("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        out.append(f"| {r['mesh']} | {r['vertices']} | {r['eps']:g} | {fmt(r['build_s_1t'])} | {fmt(r['build_s_2t'])} | "
                   f"{fmt(r['build_s_1t'] / r['build_s_2t'], 2)}x | {fmt(r['candidate_s_1t'])} | {fmt(r['pruning_s_1t'])} | "
                   f"{fmt(r['windows_per_source'])} | {fmt(r['avg_degree'])} | {r['max_degree']} | "
                   f"{r['candidate_edges']} → {r['edges']} | {fmt(r['file_mb'])} | {fmt(r['peak_mem_mb'])} |")
    out.append("\n## Distance fields (single source, median of the 3 truth sources)\n")
    out.append("Accuracy is against the exact fields in `../shared/truth` (mean and max relative error, in units of ε). "
               "CGAL heat columns are CGAL 5.5's heat method (plain / intrinsic Delaunay) from the same truth directory.\n")
    out.append("| mesh | ε | DGG label-correcting (ms) | Dijkstra on same graph (ms) | LC speed-up | ns / vertex | queue pops / vertex | mean err (ε) | max err (ε) | most below exact | CGAL heat mean err | CGAL heat-IDT mean err | our exact field (s) | exact windows / vertex | exact engine max rel err |")
    out.append("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        out.append(f"| {r['mesh']} | {r['eps']:g} | {fmt(r['field_lc_ms'])} | {fmt(r['field_dijkstra_ms'])} | "
                   f"{fmt(r['field_dijkstra_ms'] / r['field_lc_ms'], 2)}x | {fmt(r['field_ns_per_vertex'])} | {fmt(r['pops_per_vertex'])} | "
                   f"{fmt(r['field_mean_err_eps'])} | {fmt(r['field_max_err_eps'])} | {fmt(r['field_most_under'])} | "
                   f"{fmt(r['cgal_heat_mean_err'])} | {fmt(r['cgal_heat_idt_mean_err'])} | {fmt(r['exact_field_s'])} | "
                   f"{fmt(r['exact_windows_per_vertex'])} | {fmt(r['exact_max_err'])} |")
    out.append("\n## Point-to-point (the shared exact pairs: inside faces, on edges, at vertices, same face)\n")
    out.append("| mesh | ε | p50 (ms) | p90 (ms) | p99 (ms) | mean err (ε) | max err (ε) | nodes settled, A* | nodes settled, bidirectional Dijkstra | path p50 (ms) | graph open (ms) |")
    out.append("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        if "p2p_p50_ms" not in r:
            continue
        out.append(f"| {r['mesh']} | {r['eps']:g} | {fmt(r['p2p_p50_ms'])} | {fmt(r['p2p_p90_ms'])} | {fmt(r['p2p_p99_ms'])} | "
                   f"{fmt(r['p2p_mean_err_eps'])} | {fmt(r['p2p_max_err_eps'])} | {fmt(r['astar_settled'])} | "
                   f"{fmt(r['dijkstra_settled'])} | {fmt(r['path_p50_ms'])} | {fmt(r['graph_open_ms'])} |")
    return "\n".join(out) + "\n"


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--meshes", default="eight,spot,camelhead,fertility,bunny,armadillo")
    p.add_argument("--eps", default="1e-2,1e-3")
    p.add_argument("--quick", action="store_true", help="50 pairs per mesh")
    p.add_argument("--out", default=os.path.join(ROOT, "bench", "results.csv"))
    p.add_argument("--markdown", default=os.path.join(ROOT, "bench", "results.md"))
    a = p.parse_args()
    start = time.time()
    rows = []
    for name in a.meshes.split(","):
        bench_mesh(name, [float(e) for e in a.eps.split(",")], rows, a.quick)
    with open(a.out, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=sorted({k for r in rows for k in r}))
        w.writeheader()
        w.writerows(rows)
    command = "bench/run_benchmarks.py " + " ".join(sys.argv[1:])
    open(a.markdown, "w").write(write_markdown(rows, command, time.time() - start))
    print(f"wrote {a.out} and {a.markdown}")


if __name__ == "__main__":
    main()
