#!/usr/bin/env python3
"""One request's pairs on one core and on two: the served time of a Distance
call with many random face-point pairs, from a daemon pinned to one CPU
(taskset; its thread pools then see one core) and from one on every CPU,
both mapping the same graph, timed alternately in the same run.

  bench/pairs_threads_bench.py [--mesh armadillo] [--eps 1e-3] [--pairs 1000] \
      [--repeats 7] [--cpus 0,1]

Prints a Markdown table for BENCHMARKS.md (bench/measurements.md) and the
rows as JSON on stderr.
"""
import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "client", "python"))
sys.path.insert(0, os.path.join(ROOT, "tests", "server"))
from geodesic_client import Client, FacePoints  # noqa: E402
from daemon_ports import stop, wait_for_ports, watch  # noqa: E402
from shared_data import SHARED  # noqa: E402


def start(bin_dir, work, mesh_dir, cpus, tag):
    """A daemon over `mesh_dir` and the graph directory in `work`, pinned to
    `cpus` (taskset's list), and a client for it."""
    port_file = os.path.join(work, f"ports-{tag}.json")
    if os.path.exists(port_file):
        os.remove(port_file)
    command = ["taskset", "-c", cpus, f"{bin_dir}/geodesicd", "serve", "--listen", "127.0.0.1:0",
               "--port-file", port_file, "--graph-dir", os.path.join(work, "graphs"),
               "--mesh-root", mesh_dir, "--no-sample"]
    daemon = watch(subprocess.Popen(command, stderr=subprocess.DEVNULL))
    ports = wait_for_ports(daemon, port_file, timeout=120)
    return daemon, Client(f"127.0.0.1:{ports['grpc']}")


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mesh", default="armadillo", help="a mesh of ../shared/meshes")
    ap.add_argument("--eps", type=float, default=1e-3)
    ap.add_argument("--pairs", type=int, default=1000)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--cpus", default="0,1", help="taskset CPU list of the wider daemon")
    ap.add_argument("--bin", default=os.path.join(ROOT, "build", "bin"))
    args = ap.parse_args()
    mesh_file = next(f for f in os.listdir(os.path.join(SHARED, "meshes"))
                     if os.path.splitext(f)[0] == args.mesh)
    work = tempfile.mkdtemp(prefix="pairs_bench_")
    try:
        mesh_dir = os.path.join(work, "meshes")
        os.makedirs(mesh_dir)
        shutil.copy(os.path.join(SHARED, "meshes", mesh_file), mesh_dir)
        # Build once on every CPU; both daemons then map the graph file.
        daemon, client = start(args.bin, work, mesh_dir, args.cpus, "build")
        client.register_mesh(args.mesh, mesh_file)
        client.request_graph(args.mesh, args.eps, wait=True)
        faces = client.mesh(args.mesh).diagnostics.faces
        stop(daemon)

        rng = np.random.default_rng(7)

        def random_points():
            b = rng.random((args.pairs, 3))
            return FacePoints(rng.integers(0, faces, args.pairs), b / b.sum(axis=1, keepdims=True))

        a, b = random_points(), random_points()
        runs = {}
        for cpus in ("0", args.cpus):
            daemon, client = start(args.bin, work, mesh_dir, cpus, cpus.replace(",", "-"))
            if args.mesh not in [m.name for m in client.meshes()]:  # restored from the catalog
                client.register_mesh(args.mesh, mesh_file)
            client.request_graph(args.mesh, args.eps, wait=True)
            client.distances(args.mesh, a, b, args.eps)  # warm: graph pages, landmarks
            runs[cpus] = (daemon, client)
        times = {cpus: [] for cpus in runs}
        answers = {}
        for _ in range(args.repeats):
            for cpus, (_, client) in runs.items():
                t = time.perf_counter()
                answers[cpus] = client.distances(args.mesh, a, b, args.eps)
                times[cpus].append(time.perf_counter() - t)
        for daemon, client in runs.values():
            client.close()
            stop(daemon)
        one, many = (np.asarray(answers[c]) for c in ("0", args.cpus))
        assert one.size == args.pairs and np.isfinite(one).all(), "one-CPU answers not all finite"
        assert np.array_equal(one, many), "the two daemons answered different distances"
        t1, t2 = statistics.median(times["0"]), statistics.median(times[args.cpus])
        row = {"mesh": args.mesh, "eps": args.eps, "pairs": args.pairs, "repeats": args.repeats,
               "seconds_1cpu": t1, "seconds_wide": t2, "wide_cpus": args.cpus,
               "speedup": t1 / t2, "machine": f"{platform.machine()}, {os.cpu_count()} cores"}
        print(json.dumps(row), file=sys.stderr)
        print(f"Command: `bench/pairs_threads_bench.py --mesh {args.mesh} --eps {args.eps:g} "
              f"--pairs {args.pairs} --repeats {args.repeats} --cpus {args.cpus}`; "
              f"{row['machine']}; one Distance request of random face-point pairs (seed 7), "
              f"median of {args.repeats}, the two daemons timed alternately.\n")
        print("| mesh | ε | pairs | 1 CPU (s) | CPUs " + args.cpus + " (s) | speed-up |")
        print("|---|---:|---:|---:|---:|---:|")
        print(f"| {args.mesh} | {args.eps:g} | {args.pairs} | {t1:.3f} | {t2:.3f} | "
              f"{t1 / t2:.2f}x |")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
