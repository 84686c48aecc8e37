#!/usr/bin/python3
"""Load on the daemon: concurrent gRPC clients doing pairs, fields or small matrices.

Starts `geodesicd serve` on 127.0.0.1 port 0 on its default admission flags (--max-inflight,
--query-threads, --max-streams) and the given --memory-limit, waits for the mesh's graph, then
for each kind of query and each client count runs that many client threads (one channel
each) for --seconds, and writes a "Load" section (throughput, p50/p99, overload answers, peak
RSS against the limit) to --out, a file run_benchmarks.py carries into BENCHMARKS.md.

Usage: load_bench.py --bin build/bin [--mesh data/spot.obj] [--eps 1e-3] [--clients 1,16,64]
                     [--seconds 3] [--memory-limit 300M] [--out bench/load.md]
"""
import argparse
import os
import platform
import re
import shlex
import shutil
import sys
import tempfile
import threading
import time
import urllib.request

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "client", "python"))
sys.path.insert(0, os.path.join(ROOT, "tests", "server"))
import grpc  # noqa: E402
from geodesic_client._stubs import pb, rpc  # noqa: E402
from daemon_ports import start_daemon  # noqa: E402

SIZES = {"K": 1 << 10, "M": 1 << 20, "G": 1 << 30}


def byte_size(text):
    m = re.fullmatch(r"(\d+)([KMG]?)", text)
    return int(m.group(1)) * SIZES.get(m.group(2), 1)


def rss(pid, field="VmRSS"):
    with open(f"/proc/{pid}/status") as f:
        return int(re.search(rf"^{field}:\s+(\d+) kB", f.read(), re.M).group(1)) << 10


# The gauges of what --memory-limit counts.
COUNTED = ("mesh_resident_bytes", "graph_resident_bytes", "graph_mapped_bytes",
           "query_scratch_bytes")


def counted_bytes(port):
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=10) as r:
        text = r.read().decode()
    return sum(float(re.search(rf"^geodesicd_{g} (\S+)$", text, re.M).group(1)) for g in COUNTED)


def ops(mesh, eps, vertices):
    def point(v):
        return pb.SurfacePoint(vertex=v % vertices)

    def pairs(stub, seed, md):
        stub.Distance(pb.DistanceRequest(mesh=mesh, epsilon=eps, pairs=[
            pb.PointPair(**{"from": point(seed + k), "to": point(seed * 31 + k * 97)})
            for k in range(8)]), timeout=120, metadata=md)

    def field(stub, seed, md):
        for _ in stub.DistanceField(pb.DistanceFieldRequest(
                mesh=mesh, epsilon=eps, sources=[point(seed)]), timeout=120, metadata=md):
            pass

    def matrix(stub, seed, md):
        stub.Matrix(pb.MatrixRequest(mesh=mesh, epsilon=eps,
                                     sources=[point(seed + k) for k in range(3)],
                                     targets=[point(seed * 13 + k) for k in range(40)]),
                    timeout=120, metadata=md)

    return {"pairs (8 per call)": pairs, "field": field, "matrix 3 x 40": matrix}


def run_cell(port, op, clients, seconds, pid):
    latencies, codes, lock, stop = [], {}, threading.Lock(), threading.Event()
    peak = [0]

    def client(i):
        # Each a client of its own to the daemon's fair share (a bearer token
        # of its own; the daemon asks for none), as separate processes are.
        md = [("authorization", f"Bearer load-client-{i}")]
        with grpc.insecure_channel(f"127.0.0.1:{port}") as channel:
            stub = rpc.GeodesicStub(channel)
            n = 0
            while not stop.is_set():
                n += 1
                start = time.perf_counter()
                try:
                    op(stub, i * 7919 + n, md)
                    code = "OK"
                except grpc.RpcError as e:
                    code = e.code().name
                elapsed = time.perf_counter() - start
                with lock:
                    codes[code] = codes.get(code, 0) + 1
                    if code == "OK":
                        latencies.append(elapsed)
                if code == "RESOURCE_EXHAUSTED":
                    time.sleep(0.01)

    threads = [threading.Thread(target=client, args=(i,)) for i in range(clients)]
    start = time.perf_counter()
    for t in threads:
        t.start()
    while time.perf_counter() - start < seconds:
        peak[0] = max(peak[0], rss(pid))
        time.sleep(0.05)
    stop.set()
    for t in threads:
        t.join()
    wall = time.perf_counter() - start
    latencies.sort()

    def pct(q):
        return 1e3 * latencies[min(len(latencies) - 1, int(q * len(latencies)))] if latencies \
            else float("nan")

    return {"qps": len(latencies) / wall, "p50": pct(0.5), "p99": pct(0.99),
            "overload": codes.get("RESOURCE_EXHAUSTED", 0),
            "other": sum(v for k, v in codes.items() if k not in ("OK", "RESOURCE_EXHAUSTED")),
            "peak": peak[0]}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bin", default=os.path.join(ROOT, "build", "bin"))
    ap.add_argument("--mesh", default=os.path.join(ROOT, "data", "spot.obj"))
    ap.add_argument("--eps", type=float, default=1e-3)
    ap.add_argument("--clients", default="1,16,64")
    ap.add_argument("--seconds", type=float, default=3)
    ap.add_argument("--memory-limit", default="300M")
    ap.add_argument("--note", default="", help="a sentence on the machine's state")
    ap.add_argument("--out", default=os.path.join(ROOT, "bench", "load.md"))
    args = ap.parse_args()
    clients = [int(c) for c in args.clients.split(",")]
    limit = byte_size(args.memory_limit)
    work = tempfile.mkdtemp()
    daemon, ports = start_daemon(args.bin, work, [
        "--graph-dir", f"{work}/graphs", "--log-level", "warning", "--no-sample",
        "--mesh-root", os.path.dirname(os.path.abspath(args.mesh)),
        "--memory-limit", args.memory_limit], metrics=True)
    try:
        with grpc.insecure_channel(f"127.0.0.1:{ports['grpc']}") as channel:
            stub = rpc.GeodesicStub(channel)
            name = os.path.splitext(os.path.basename(args.mesh))[0]
            mesh = stub.RegisterMesh(pb.RegisterMeshRequest(
                name=name, path=os.path.basename(args.mesh)),
                                     timeout=600)
            vertices = mesh.diagnostics.vertices
            stub.RequestGraph(pb.RequestGraphRequest(mesh=name, epsilon=args.eps), timeout=60)
            while stub.GetGraph(pb.GetGraphRequest(mesh=name, epsilon=args.eps),
                                timeout=60).state != pb.GRAPH_STATE_READY:
                time.sleep(0.2)
            pairs_op = ops(name, args.eps, vertices)["pairs (8 per call)"]
            pairs_op(stub, 1)  # the first query's allocations belong to the idle state
            idle = rss(daemon.pid)
            counted = counted_bytes(ports["metrics"])
        rows = []
        for label, op in ops(name, args.eps, vertices).items():
            for n in clients:
                cell = run_cell(ports["grpc"], op, n, args.seconds, daemon.pid)
                rows.append((label, n, cell))
                print(label, n, cell, file=sys.stderr)
        hwm = rss(daemon.pid, "VmHWM")
    finally:
        daemon.terminate()
        daemon.wait(timeout=60)
        shutil.rmtree(work)
    command = shlex.join(["bench/load_bench.py"] + sys.argv[1:])
    out = ["## Load: concurrent clients on default admission flags\n",
           f"Regenerate: `{command}`. Machine: {os.cpu_count()} cores, {platform.platform()}. "
           f"Mesh {os.path.basename(args.mesh)} ({vertices} vertices), ε = {args.eps:g}, daemon on "
           f"default flags (--max-inflight 64, --query-threads = cores, --max-streams 64) with "
           f"--memory-limit {args.memory_limit}; each client a Python thread with its own "
           f"channel, {args.seconds:g} s per cell, on the same cores as the daemon. "
           + (args.note + " " if args.note else "") +
           "p50/p99 are of answered calls, as the client measured them; \"overload\" counts "
           "RESOURCE_EXHAUSTED answers, \"other\" every other error.\n",
           "| query | clients | answered/s | p50 (ms) | p99 (ms) | overload | other | "
           "peak RSS (MiB) |",
           "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for label, n, c in rows:
        out.append(f"| {label} | {n} | {c['qps']:.0f} | {c['p50']:.2f} | {c['p99']:.2f} | "
                   f"{c['overload']} | {c['other']} | {c['peak'] / 2**20:.0f} |")
    out.append("")
    out.append(f"Resident memory: {idle / 2**20:.0f} MiB idle with the graph ready, of which the "
               f"gauges --memory-limit counts (mesh, graph, scratch) are {counted / 2**20:.0f} MiB: "
               f"the fixed overhead (binary, gRPC, threads' stacks) that docs/limits.md's "
               f"`--memory-limit` text names is the difference, {(idle - counted) / 2**20:.0f} MiB. "
               f"High-water mark over the whole run {hwm / 2**20:.0f} MiB, against a limit of "
               f"{limit / 2**20:.0f} MiB.")
    with open(args.out, "w") as f:
        f.write("\n".join(out) + "\n")
    print("\n".join(out))


if __name__ == "__main__":
    main()
