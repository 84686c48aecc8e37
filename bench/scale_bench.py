#!/usr/bin/env python3
"""Scale benchmark: build, open and query the graph of a large mesh.

    scale_bench.py --mesh ../shared/meshes/armadillo_loop2.ply --subdivide 1 \\
        --eps 1e-3 --threads 2 --work /tmp/scale

With --subdivide K the mesh is first subdivided 1-to-4 K times
(bench/subdivide_mesh.py; 800K -> 3.2M vertices for K = 1), so no large file
is stored. Reports, as JSON and as a Markdown line for BENCHMARKS.md: build
time and phases, peak resident memory (the build's own getrusage, which counts
the graph file's pages the build maps) and peak anonymous memory (sampled),
graph file
and mesh bytes and the peak's ratio to their sum, graph open time (header
checks and map; and with every checksum and index checked), field solve time
from a few vertices, and point-to-point latency between random face points.
A graph already in --work (with its build.json) is reused unless --rebuild.
"""
import argparse
import json
import os
import random
import statistics
import subprocess
import sys

from process_memory import peak_anonymous_bytes

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def run(args, env=None):
    result = subprocess.run(args, capture_output=True, text=True, env=env)
    if result.returncode != 0:
        sys.exit(f"{' '.join(args)} failed ({result.returncode}):\n{result.stderr[-2000:]}")
    return result.stdout


def run_sampled(args):
    """Runs a command, sampling its resident anonymous memory every 0.1 s;
    returns its output and the largest sample in bytes."""
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    peak = peak_anonymous_bytes(proc, 0.1)
    out, err = proc.communicate()
    if proc.returncode != 0:
        sys.exit(f"{' '.join(args)} failed ({proc.returncode}):\n{err[-2000:]}")
    return out, peak


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--mesh", required=True)
    parser.add_argument("--subdivide", type=int, default=0)
    parser.add_argument("--eps", type=float, default=1e-3)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--work", required=True, help="directory for the mesh, graph and results")
    parser.add_argument("--bin", default=os.path.join(ROOT, "build", "bin"))
    parser.add_argument("--sources", type=int, default=3, help="field sources (vertices)")
    parser.add_argument("--pairs", type=int, default=200, help="face-point pairs")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--rebuild", action="store_true")
    parser.add_argument("--build-memory-limit", help="passed to geodesicd build")
    args = parser.parse_args()
    os.makedirs(args.work, exist_ok=True)
    geodesicd = os.path.join(args.bin, "geodesicd")

    mesh = args.mesh
    if args.subdivide:
        mesh = os.path.join(args.work, f"subdivided{args.subdivide}.ply")
        if not os.path.exists(mesh):
            run(["/usr/bin/python3", os.path.join(HERE, "subdivide_mesh.py"), args.mesh, mesh,
                 "--times", str(args.subdivide)])
    info = json.loads(run([geodesicd, "info", mesh, "--json"]))
    vertices, faces = info["vertices"], info["faces"]

    graph = os.path.join(args.work, f"graph-{args.eps:g}.dgg")
    build_json = graph + ".build.json"
    if args.rebuild or not os.path.exists(build_json) or not os.path.exists(graph):
        limit = ["--build-memory-limit", args.build_memory_limit] if args.build_memory_limit else []
        out, anonymous = run_sampled([geodesicd, "build", mesh, "--eps", str(args.eps),
                                      "--threads", str(args.threads), "--json", "--quiet",
                                      "--out", graph] + limit)
        build = json.loads(out)
        build["peak_anonymous_bytes"] = anonymous
        with open(build_json, "w") as f:
            json.dump(build, f)
    with open(build_json) as f:
        build = json.load(f)

    env = dict(os.environ, GEODESIC_BENCH_MESH=mesh, GEODESIC_BENCH_GRAPH=graph,
               GEODESIC_BENCH_EPS=str(args.eps))
    bench = json.loads(run([os.path.join(args.bin, "micro_benchmarks"),
                            "--benchmark_filter=BM_GraphOpen", "--benchmark_repetitions=3",
                            "--benchmark_report_aggregates_only=true",
                            "--benchmark_format=json"], env=env))
    open_ms = {}
    for b in bench["benchmarks"]:
        if b.get("aggregate_name") == "median":
            open_ms[b["label"]] = b["real_time"] / 1e3  # microseconds -> ms

    rng = random.Random(args.seed)
    field_ms = []
    for _ in range(args.sources):
        out = run([geodesicd, "field", "--mesh", mesh, "--graph", graph, "--source",
                   f"v:{rng.randrange(vertices)}", "--out", os.path.join(args.work, "field.f64"),
                   "--json"])
        field_ms.append(1e3 * json.loads(out)["solve_seconds"])

    def face_point():  # coordinates in 1/1024ths, so that they sum to 1 exactly
        a, b = rng.randrange(1, 1023), rng.randrange(1, 1023)
        if a + b >= 1024:
            a, b = 1024 - a, 1024 - b
        return f"f:{rng.randrange(faces)}:{a / 1024!r},{b / 1024!r},{(1024 - a - b) / 1024!r}"

    pairs_file = os.path.join(args.work, "pairs.txt")
    with open(pairs_file, "w") as f:
        for _ in range(args.pairs):
            f.write(f"{face_point()} {face_point()}\n")
    answers = json.loads(run([geodesicd, "distance", "--mesh", mesh, "--graph", graph,
                              "--pairs", pairs_file, "--json"]))
    pair_ms = sorted(1e3 * a["seconds"] for a in answers)

    summary = {
        "mesh": os.path.basename(args.mesh), "subdivide": args.subdivide, "vertices": vertices,
        "eps": args.eps, "threads": args.threads,
        "build_seconds": build["build_seconds"], "candidate_seconds": build["candidate_seconds"],
        "fan_seconds": build["fan_seconds"], "edges": build["edges"],
        "average_degree": build["average_degree"],
        "peak_memory_bytes": build["peak_memory_bytes"], "file_bytes": build["file_bytes"],
        "peak_anonymous_bytes": build.get("peak_anonymous_bytes"),
        "spilled_bytes": build.get("spilled_bytes"),
        "mesh_bytes": build["mesh_bytes"],
        "peak_over_file_and_mesh": build["peak_memory_bytes"] /
                                   (build["file_bytes"] + build["mesh_bytes"]),
        "open_ms": open_ms, "field_ms": field_ms,
        "pair_p50_ms": statistics.median(pair_ms),
        "pair_p95_ms": pair_ms[int(0.95 * (len(pair_ms) - 1))],
    }
    print(json.dumps(summary, indent=1))
    gb = 1e9
    print(f"| {summary['mesh']}{' x' + str(4 ** args.subdivide) if args.subdivide else ''} "
          f"| {vertices:,} | {args.eps:g} | {args.threads} | {build['build_seconds']:.0f} s "
          f"| {build['peak_memory_bytes'] / gb:.2f} GB | {build['file_bytes'] / gb:.2f} GB "
          f"| {build['mesh_bytes'] / gb:.2f} GB | {summary['peak_over_file_and_mesh']:.2f} "
          f"| {open_ms.get('header', float('nan')):.1f} / {open_ms.get('full', float('nan')):.0f} ms "
          f"| {statistics.median(field_ms):.0f} ms | {summary['pair_p50_ms']:.2f} / "
          f"{summary['pair_p95_ms']:.2f} ms |")


if __name__ == "__main__":
    main()
