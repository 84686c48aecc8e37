#!/usr/bin/env python3
"""Our builds and fields beside FastDGG's (Adikusuma, Fang, He, ACM TOG 2020,
the authors' public code) in the same run: per mesh and ε, one-thread builds
of both, alternating on one pinned CPU for a few rounds, their files and peak
memory, then single-source fields on both graphs and their errors against
the exact truth.

  bench/fastdgg_peer_bench.py --fastdgg DIR [--geodesicd build/bin/geodesicd]
      [--micro build/bin/micro_benchmarks] [--meshes armadillo,bunny]
      [--eps 1e-2,1e-3] [--rounds 3] [--cpu 1] [--build-memory-limit 20M]

FastDGG is not part of this project and is not vendored: build it yourself
from github.com/GeodesicGraph/DGG_and_SVG (src/ only). Its code is written
for MSVC; with g++ on Debian 12 it needs the Windows headers dropped
(windows.h, tchar.h, omp.h, Shlwapi.h, conio.h), its QueryPerformanceCounter
timer and GetTickCount replaced by std::chrono, DeleteFile by std::remove,
backslashes in #include paths turned round and two include names lowercased,
the standard headers MSVC includes implicitly added, temporaries bound to
non-const references made const (AddIntoQueueOfPseudoSources) or values
(`v.swap(vector<T>(v))` becomes `vector<T>(v).swap(v)`), `using` declarations
for the base members of its Dijkstra<T> template, the extra `CPoint3D::`
on Normalize's declaration in its class dropped, and _finite by
std::isfinite. Then, in DIR, `g++ -O3 -DNDEBUG -std=c++17 -pthread -Isrc`
builds DGG_Precompute from src/DGG_precompute/{main,FastDGG,SVG,
dgg_precompute}.cpp and src/ICH/*.cpp, and DGG_Solution from
src/DGG_Solution/dgg_solution.cpp and src/ICH/{BaseModel,Point3D,
RichModel}.cpp: the same flags as ours (no -march=native).

What is timed:
- Build: wall time of each process, mesh reading and file writing included,
  and its peak memory: resident anonymous memory (RssAnon, sampled every 50
  ms) and getrusage's peak, which also counts mapped file pages (our builds
  keep the edge array in the mapped graph file); for us also `build_seconds` (the
  build alone), for FastDGG the last "Time Elapsed" its progress line
  printed (its propagation alone, without its part-file merge: a lower
  bound on its build).
- Field from vertex 0: FastDGG's printed time, its Dijkstra alone on a graph
  read into memory; ours on a resident graph the same way
  (`micro_benchmarks` BM_Field/0, the label-correcting solver from a
  different vertex each iteration), and in a new `geodesicd field` process,
  whose solve also faults in the graph's mapping.
- Errors: both fields from vertex 0 against ../shared/truth's exact field,
  relative, over the vertices the truth reaches (FastDGG's distances are
  float32).

Prints two Markdown tables for bench/measurements.md.
"""
import argparse
import glob
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

from exact_ab_bench import mesh_file
from process_memory import peak_anonymous_bytes
from shared_data import SHARED
from vtp_peer_bench import as_obj

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


class Run:
    """A finished process: its output, wall time, getrusage's peak (which
    counts mapped file pages: our builds write their edges into the mapped
    graph file) and the peak of its resident anonymous memory, sampled."""

    def __init__(self, stdout, stderr, wall, peak_rss, peak_anon):
        self.stdout, self.stderr = stdout, stderr
        self.wall, self.peak_rss, self.peak_anon = wall, peak_rss, peak_anon


def timed(cmd, cpu, env=None):
    """Runs cmd pinned to cpu under /usr/bin/time (whose getrusage peak is the
    command's own: a child of this script would count the script's memory
    before its exec), sampling its RssAnon every 50 ms."""
    with tempfile.NamedTemporaryFile("r") as stats, tempfile.TemporaryFile("w+") as out, \
            tempfile.TemporaryFile("w+") as err:
        start = time.monotonic()
        proc = subprocess.Popen(["/usr/bin/time", "-f", "%M", "-o", stats.name, "taskset", "-c",
                                 str(cpu)] + cmd, stdout=out, stderr=err, text=True, env=env)
        peak_anon = peak_anonymous_bytes(proc, 0.05)
        wall = time.monotonic() - start
        out.seek(0)
        err.seek(0)
        run = Run(out.read(), err.read(), wall, 0, peak_anon)
        if proc.returncode != 0:
            sys.exit(f"{' '.join(cmd)} failed:\n{run.stdout[-2000:]}{run.stderr[-2000:]}")
        run.peak_rss = int(stats.read().split()[-1]) * 1024
    return run


def build_ours(args, mesh, eps, out):
    limit = ["--build-memory-limit", args.build_memory_limit] if args.build_memory_limit else []
    run = timed([args.geodesicd, "build", mesh, "--eps", str(eps), "--threads", "1", "--out", out,
                 "--json", "--quiet"] + limit, args.cpu)
    run.seconds = json.loads(run.stdout)["build_seconds"]
    return run


def build_theirs(args, obj, eps, work):
    for old in glob.glob(os.path.join(work, "*_FD*.binary")):
        os.remove(old)
    run = timed([os.path.join(args.fastdgg, "DGG_Precompute"), "f", obj, str(eps), "1"], args.cpu)
    elapsed = re.findall(r"Time Elapsed: ([0-9.]+) s", run.stdout)
    graphs = glob.glob(os.path.join(work, "*_FD*.binary"))
    if not elapsed or len(graphs) != 1:
        sys.exit(f"DGG_Precompute on {obj}: unexpected output:\n{run.stdout[-2000:]}")
    run.seconds, run.graph = float(elapsed[-1]), graphs[0]
    return run


def field_theirs(args, obj, graph, out):
    run = timed([os.path.join(args.fastdgg, "DGG_Solution"), "SSAD", obj, graph, "0", out],
                args.cpu)
    seconds = run.stderr.split()
    if not seconds:
        sys.exit(f"DGG_Solution: no time printed:\n{run.stdout[-2000:]}")
    return float(seconds[-1]), np.loadtxt(out, skiprows=1)


def field_ours(args, mesh, graph, out):
    run = timed([args.geodesicd, "field", "--mesh", mesh, "--graph", graph, "--source", "v:0",
                 "--out", out, "--json"], args.cpu)
    return json.loads(run.stdout)["solve_seconds"], np.fromfile(out)


def field_ours_resident(args, mesh, graph):
    env = dict(os.environ, GEODESIC_BENCH_MESH=mesh, GEODESIC_BENCH_GRAPH=graph)
    run = timed([args.micro, "--benchmark_filter=BM_Field/0$", "--benchmark_format=json",
                 "--benchmark_min_time=1"], args.cpu, env)
    runs = json.loads(run.stdout)["benchmarks"]
    if len(runs) != 1 or runs[0]["time_unit"] != "ms":
        sys.exit(f"micro_benchmarks: unexpected output:\n{run.stdout[-2000:]}")
    return runs[0]["real_time"] / 1e3


def errors(field, truth):
    """Mean and max relative error of field against the exact truth."""
    reached = np.isfinite(truth) & (truth > 0)
    if field.size != truth.size or not reached.any() or not np.isfinite(field[reached]).all():
        sys.exit(f"a field of {field.size} values against a truth of {truth.size}, or unreached")
    rel = (field[reached] - truth[reached]) / truth[reached]
    return float(rel.mean()), float(rel.max())


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--fastdgg", required=True,
                        help="directory holding DGG_Precompute and DGG_Solution")
    parser.add_argument("--geodesicd", default=os.path.join(ROOT, "build", "bin", "geodesicd"))
    parser.add_argument("--micro", default=os.path.join(ROOT, "build", "bin", "micro_benchmarks"))
    parser.add_argument("--meshes", default="armadillo,bunny")
    parser.add_argument("--eps", default="1e-2,1e-3")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--cpu", type=int, default=1)
    parser.add_argument("--build-memory-limit",
                        help="passed to our builds (e.g. 20M): candidate edges beyond it spill")
    args = parser.parse_args()
    builds, fields = [], []
    with tempfile.TemporaryDirectory() as work:
        for name in args.meshes.split(","):
            mesh = mesh_file(name)
            # FastDGG writes its graph beside the mesh it reads.
            obj = os.path.join(work, name + ".obj")
            if mesh.endswith(".obj"):
                shutil.copy(mesh, obj)
            else:
                as_obj(mesh, work)
            truth = np.fromfile(os.path.join(SHARED, "truth", f"{name}.exact.s0.f64"))
            for eps in (float(e) for e in args.eps.split(",")):
                ours_graph = os.path.join(work, "ours.dgg")
                ours, theirs = [], []
                for _ in range(args.rounds):
                    ours.append(build_ours(args, mesh, eps, ours_graph))
                    theirs.append(build_theirs(args, obj, eps, work))
                their_graph = theirs[-1].graph
                o_build = statistics.median(r.seconds for r in ours)
                o_wall = statistics.median(r.wall for r in ours)
                t_prop = statistics.median(r.seconds for r in theirs)
                t_wall = statistics.median(r.wall for r in theirs)
                o_rss, t_rss = max(r.peak_rss for r in ours), max(r.peak_rss for r in theirs)
                o_anon, t_anon = max(r.peak_anon for r in ours), max(r.peak_anon for r in theirs)
                o_file, t_file = os.path.getsize(ours_graph), os.path.getsize(their_graph)
                builds.append(
                    f"| {name} | {eps:g} | {o_build:.2f} | {o_wall:.2f} | {t_prop:.2f} | "
                    f"{t_wall:.2f} | {t_wall / o_wall:.2f}x | {t_prop / o_build:.2f}x | "
                    f"{o_file / 1e6:.1f} | {t_file / 1e6:.1f} | {o_anon / 1e6:.0f} / "
                    f"{o_rss / 1e6:.0f} | {t_anon / 1e6:.0f} / {t_rss / 1e6:.0f} |")
                print(builds[-1], flush=True)
                o_solve, t_solve = [], []
                for _ in range(args.rounds):
                    o_seconds, o_field = field_ours(args, mesh, ours_graph, f"{work}/ours.f64")
                    t_seconds, t_field = field_theirs(args, obj, their_graph, f"{work}/fd.txt")
                    o_solve.append(o_seconds)
                    t_solve.append(t_seconds)
                resident = field_ours_resident(args, mesh, ours_graph)
                t_med = statistics.median(t_solve)
                (o_mean, o_max), (t_mean, t_max) = errors(o_field, truth), errors(t_field, truth)
                fields.append(
                    f"| {name} | {eps:g} | {resident * 1e3:.2f} | "
                    f"{statistics.median(o_solve) * 1e3:.2f} | {t_med * 1e3:.2f} | "
                    f"{t_med / resident:.1f}x | {t_med / statistics.median(o_solve):.1f}x | "
                    f"{o_mean / eps:.3f} / {o_max / eps:.2f} | {t_mean / eps:.3f} / "
                    f"{t_max / eps:.2f} |")
                print(fields[-1], flush=True)
    print("\n| mesh | ε | ours: build (s) | ours: wall (s) | FastDGG: propagation (s) "
          "| FastDGG: wall (s) | FastDGG / ours, wall | FastDGG propagation / our build "
          "| ours: file (MB) | FastDGG: file (MB) | ours: peak anonymous / getrusage (MB) "
          "| FastDGG: peak anonymous / getrusage (MB) |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    print("\n".join(builds))
    print("\n| mesh | ε | ours: field, resident (ms) | ours: field, new process (ms) "
          "| FastDGG: field (ms) | FastDGG / ours, resident | FastDGG / ours, new process "
          "| ours: mean / max error (ε) | FastDGG: mean / max error (ε) |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    print("\n".join(fields))


if __name__ == "__main__":
    main()
