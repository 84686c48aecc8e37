#!/usr/bin/env python3
"""The daemon as users meet it: loopback point-to-point latency and throughput
with the CLI's bench, a streamed distance field against the core's own solve
time, and a restart that maps a large graph instead of rebuilding it.

Writes a Markdown section to bench/daemon.md, which bench/run_benchmarks.py
carries into BENCHMARKS.md (and prints the raw figures as JSON on stderr). Every daemon listens on 127.0.0.1 and is stopped at the end; every
load is bounded by --duration.

  bench/daemon_bench.py --mesh armadillo.obj --eps 1e-3 \\
      --big armadillo_loop2.ply --big-eps 1e-2 --duration 10
"""
import argparse
import json
import os
import platform
import random
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time

from shared_data import SHARED

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.join(ROOT, "build", "bin")


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Daemon:
    def __init__(self, graph_dir, mesh_root, log):
        self.address = "127.0.0.1:%d" % free_port()
        self.started = time.monotonic()
        self.proc = subprocess.Popen(
            [os.path.join(BIN, "geodesicd"), "serve", "--listen", self.address,
             "--graph-dir", graph_dir, "--mesh-root", mesh_root, "--no-sample",
             "--log-level", "warning"],
            stdout=log, stderr=log)
        deadline = time.monotonic() + 60
        while self.cli("meshes", check=False).returncode != 0:
            if time.monotonic() > deadline or self.proc.poll() is not None:
                raise RuntimeError("geodesicd did not start on " + self.address)
            time.sleep(0.05)
        self.ready_seconds = time.monotonic() - self.started

    def cli(self, *args, check=True, mesh=None, eps=None):
        cmd = [os.path.join(BIN, "geodesic"), "--server", self.address, "--timeout", "3600"]
        if mesh:
            cmd += ["--mesh", mesh]
        if eps:
            cmd += ["--eps", str(eps)]
        r = subprocess.run(cmd + list(args), capture_output=True, text=True)
        if check and r.returncode != 0:
            raise RuntimeError("%s failed: %s" % (" ".join(cmd + list(args)), r.stderr))
        return r

    def json(self, *args, **kw):
        return json.loads(self.cli("--json", *args, **kw).stdout)

    def stop(self):
        self.proc.send_signal(signal.SIGTERM)
        try:
            self.proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


def wait_for_landmarks(daemon, mesh, eps, timeout=600):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for g in daemon.json("status"):
            if g["mesh"] == mesh and abs(g["epsilon"] - eps) <= 1e-12 * eps and g["landmark_bytes"]:
                return g
        time.sleep(0.2)
    raise RuntimeError("landmarks for %s were not ready in %d s" % (mesh, timeout))


def random_pairs(vertices, faces, n, face_points, rng):
    def point():
        if not face_points:
            return "v:%d" % rng.randrange(vertices)
        u, v = rng.random(), rng.random()
        if u + v > 1:
            u, v = 1 - u, 1 - v
        return "f:%d:%.17g,%.17g,%.17g" % (rng.randrange(faces), u, v, 1 - u - v)
    return ["%s %s" % (point(), point()) for _ in range(n)]


def core_pairs(mesh_path, graph_path, pairs, workdir):
    """Per-query seconds of the core (graph loaded, landmarks prepared)."""
    path = os.path.join(workdir, "pairs.txt")
    with open(path, "w") as f:
        f.write("\n".join(pairs) + "\n")
    r = subprocess.run([os.path.join(BIN, "geodesicd"), "distance", "--mesh", mesh_path,
                        "--graph", graph_path, "--pairs", path, "--json"],
                       capture_output=True, text=True, check=True)
    return [p["seconds"] for p in json.loads(r.stdout)]


def median_of(runs):
    return statistics.median(runs)


def measure_fields(daemon, args, name, vertices, graph_path, workdir, rng, out):
    """A full field: streamed to the CLI and written to a file, against the
    core's solve alone."""
    mesh_root = os.path.join(SHARED, "meshes")
    streamed, solve = [], []
    f64 = os.path.join(workdir, "field.f64")
    for run in range(args.field_runs):
        source = "v:%d" % rng.randrange(vertices)
        streamed.append(daemon.json("field", "--source", source, "--out", f64,
                                    mesh=name, eps=args.eps)["seconds"])
        r = subprocess.run([os.path.join(BIN, "geodesicd"), "field", "--mesh",
                            os.path.join(mesh_root, args.mesh), "--graph", graph_path,
                            "--source", source, "--out", f64 + ".core", "--json"],
                           capture_output=True, text=True, check=True)
        solve.append(json.loads(r.stdout)["solve_seconds"])
    out["field_streamed_ms"] = 1e3 * median_of(streamed)
    out["field_core_ms"] = 1e3 * median_of(solve)


def measure_restart(graph_dir, mesh_root, log, args, big, out):
    """A restarted daemon: how soon it listens, restores the large mesh, maps
    its graph and answers."""
    daemon = Daemon(graph_dir, mesh_root, log)
    try:
        out["restart_listening_s"] = daemon.ready_seconds
        t0 = time.monotonic()
        loaded = daemon.json("load", args.big, mesh=big)
        out["restart_mesh_load_s"] = time.monotonic() - t0
        out["restart_mesh_restored"] = loaded["restored"]
        t1 = time.monotonic()
        g = daemon.json("graph", "--wait", mesh=big, eps=args.big_eps)
        out["restart_graph_s"] = time.monotonic() - t1
        out["restart_graph_from_file"] = g["from_file"]
        t2 = time.monotonic()
        daemon.json("distance", "--from", "v:0", "--to", "v:%d" % (g["nodes"] // 2),
                    mesh=big, eps=args.big_eps)
        out["restart_first_query_s"] = time.monotonic() - t2
        out["restart_graph_to_answer_s"] = time.monotonic() - t1
        out["restart_start_to_answer_s"] = time.monotonic() - daemon.started
    finally:
        daemon.stop()


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mesh", default="armadillo.obj", help="file under ../shared/meshes")
    ap.add_argument("--eps", type=float, default=1e-3)
    ap.add_argument("--big", default="armadillo_loop2.ply", help="large mesh for the restart")
    ap.add_argument("--big-eps", type=float, default=1e-2)
    ap.add_argument("--duration", type=float, default=10, help="seconds per load phase")
    ap.add_argument("--graph-dir", help="keep graphs here between runs (default: a temp dir)")
    ap.add_argument("--field-runs", type=int, default=5)
    ap.add_argument("--markdown", default=os.path.join(ROOT, "bench", "daemon.md"),
                    help="where the Markdown section goes ('-': stdout)")
    args = ap.parse_args()

    mesh_root = os.path.join(SHARED, "meshes")
    workdir = tempfile.mkdtemp(prefix="daemon_bench_")
    graph_dir = args.graph_dir or os.path.join(workdir, "graphs")
    os.makedirs(graph_dir, exist_ok=True)
    log = open(os.path.join(workdir, "geodesicd.log"), "w")
    name = os.path.splitext(args.mesh)[0]
    big = os.path.splitext(args.big)[0]
    out = {"mesh": args.mesh, "eps": args.eps, "big": args.big, "big_eps": args.big_eps}
    rng = random.Random(1)

    daemon = Daemon(graph_dir, mesh_root, log)
    try:
        info = daemon.json("load", args.mesh, mesh=name)
        vertices, faces = info["diagnostics"]["vertices"], info["diagnostics"]["faces"]
        t0 = time.monotonic()
        g = daemon.json("graph", "--wait", mesh=name, eps=args.eps)
        out["graph_seconds"] = time.monotonic() - t0
        out["graph_from_file"] = g["from_file"]
        g = wait_for_landmarks(daemon, name, args.eps)
        out["landmark_mb"] = g["landmark_bytes"] / 1e6
        # Files are named by mesh fingerprint and epsilon.
        graph_file = [f for f in os.listdir(graph_dir) if f.startswith(info["fingerprint"])
                      and f.endswith("eps%g.dgg" % args.eps)]
        if len(graph_file) != 1:
            raise RuntimeError("expected one graph file for %s in %s, found %s" % (
                args.mesh, graph_dir, graph_file))
        graph_path = os.path.join(graph_dir, graph_file[0])

        # Point-to-point over loopback, then the core on the same kind of pairs.
        for kind, face_points in (("vertices", False), ("face points", True)):
            flags = ["--face-points"] if face_points else []
            for concurrency in (1, 2, 4):
                b = daemon.json("bench", "--concurrency", str(concurrency), "--duration",
                                str(args.duration), "--count", "100000000", *flags,
                                mesh=name, eps=args.eps)
                out["bench %s c%d" % (kind, concurrency)] = b
            secs = core_pairs(os.path.join(mesh_root, args.mesh), graph_path,
                              random_pairs(vertices, faces, 300, face_points, rng), workdir)
            out["core %s" % kind] = {
                "p50_ms": 1e3 * median_of(secs),
                "mean_ms": 1e3 * statistics.fmean(secs),
                # Both cores busy with independent queries, nothing else: an
                # upper bound on what any server could do.
                "qps_2_cores": 2 / statistics.fmean(secs),
            }

        measure_fields(daemon, args, name, vertices, graph_path, workdir, rng, out)

        # The large graph: build (or map) it once, then restart and time the
        # first answer.
        t0 = time.monotonic()
        daemon.json("load", args.big, mesh=big)
        out["big_mesh_load_s"] = time.monotonic() - t0
        t0 = time.monotonic()
        g = daemon.json("graph", "--wait", mesh=big, eps=args.big_eps)
        out["big_graph_seconds"] = time.monotonic() - t0
        out["big_graph_from_file"] = g["from_file"]
        out["big_nodes"] = g["nodes"]
        out["big_graph_mb"] = g["bytes"] / 1e6
    finally:
        daemon.stop()

    measure_restart(graph_dir, mesh_root, log, args, big, out)
    print(json.dumps(out, indent=1), file=sys.stderr)
    text = markdown(args, out)
    if args.markdown == "-":
        sys.stdout.write(text)
    else:
        with open(args.markdown, "w") as f:
            f.write(text)


def markdown(args, o):
    lines = []
    add = lines.append
    cmd = "bench/daemon_bench.py --mesh %s --eps %g --big %s --big-eps %g --duration %g" % (
        args.mesh, args.eps, args.big, args.big_eps, args.duration)
    if args.graph_dir:
        # Graphs and mesh snapshots kept from an earlier run change the
        # first registration and graph request, not the restart.
        cmd += " --graph-dir DIR (kept from an earlier run)"
    add("## The daemon over loopback\n")
    add("Regenerate: `%s`. Machine: %d cores, %s. Daemon and CLI on the same 2 cores; "
        "graph for %s at ε = %g (landmarks ready, %.1f MB). CLI processes are started per "
        "call, but each figure below is the RPC's own time as the client measured it.\n" % (
            cmd, os.cpu_count(), platform.platform(), args.mesh, args.eps, o["landmark_mb"]))
    add("| points | concurrency | queries/s | p50 (ms) | p90 (ms) | p99 (ms) | core p50 (ms) "
        "| core queries/s on 2 cores (bound) | daemon / core throughput |")
    add("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for kind in ("vertices", "face points"):
        core = o["core %s" % kind]
        for c in (1, 2, 4):
            b = o["bench %s c%d" % (kind, c)]
            add("| %s | %d | %.0f | %.3f | %.3f | %.3f | %.3f | %.0f | %.2f |" % (
              kind, c, b["qps"], b["p50_ms"], b["p90_ms"], b["p99_ms"], core["p50_ms"],
              core["qps_2_cores"], b["qps"] / core["qps_2_cores"]))
    add("\nFull distance field (median of %d sources): streamed to the CLI and written to a "
        "file in %.1f ms, the core's solve alone %.1f ms: **%.2fx** the core.\n" % (
            args.field_runs, o["field_streamed_ms"], o["field_core_ms"],
            o["field_streamed_ms"] / o["field_core_ms"]))
    add("Restart on %s (%d nodes, ε = %g, graph file %.0f MB; before the restart the daemon "
        "registered the mesh in %.2f s and its graph request took %.1f s, from_file = %s): the "
        "restarted daemon listened after %.2f s and registered the mesh in %.2f s (restored "
        "from its snapshot: %s); then the graph request found the file and mapped it in "
        "%.3f s (from_file = %s) and the first distance query answered in %.3f s: **%.2f s "
        "from the daemon's start to its first answer**, %.3f s from the graph request "
        "(wall-clock times of CLI invocations, each process's start included).\n" % (
            args.big, o["big_nodes"], args.big_eps, o["big_graph_mb"], o["big_mesh_load_s"],
            o["big_graph_seconds"], str(o["big_graph_from_file"]).lower(),
            o["restart_listening_s"], o["restart_mesh_load_s"],
            str(o["restart_mesh_restored"]).lower(), o["restart_graph_s"],
            str(o["restart_graph_from_file"]).lower(), o["restart_first_query_s"],
            o["restart_start_to_answer_s"], o["restart_graph_to_answer_s"]))
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
