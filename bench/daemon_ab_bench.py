#!/usr/bin/env python3
"""Two builds of the daemon side by side, as clients meet them: one-pair
Distance calls and whole DistanceField streams on one mesh, over loopback,
the two daemons asked in turn (which goes first swaps every round), so that
the host's swings hit both alike; their ratio is taken round by round.

  bench/daemon_ab_bench.py --before OLD/geodesicd --after build/bin/geodesicd \\
      [--mesh armadillo.obj] [--eps 0.001] [--pairs 300] [--fields 20] [--rounds 7]

Both daemons map the same graph file (built once by --after in a temporary
--graph-dir). Prints a Markdown table for bench/measurements.md: each build's
p50 per call (median over rounds) and the after/before ratio (median, least
and largest over rounds), and checks that both answer the same distances.
Every daemon listens on 127.0.0.1 and is stopped at the end.
"""
import argparse
import os
import random
import statistics
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "client", "python"))
sys.path.insert(0, os.path.join(ROOT, "tests", "server"))
import grpc  # noqa: E402
from geodesic_client._stubs import pb, rpc  # noqa: E402
import daemon_ports  # noqa: E402
from shared_data import SHARED  # noqa: E402


def start(binary, work, name, mesh_root, graph_dir):
    daemon, ports = daemon_ports.start_daemon(
        os.path.dirname(binary), os.path.join(work, name),
        ["--graph-dir", graph_dir, "--mesh-root", mesh_root, "--log-level", "warning",
         "--no-sample", "--exact-landmarks", "0"], timeout=120)
    return daemon, rpc.GeodesicStub(grpc.insecure_channel(f"127.0.0.1:{ports['grpc']}"))


def ready(stub, mesh, eps, name):
    stub.RegisterMesh(pb.RegisterMeshRequest(name="m", path=mesh), timeout=300)
    stub.RequestGraph(pb.RequestGraphRequest(mesh="m", epsilon=eps), timeout=60)
    deadline = time.time() + 1800
    while time.time() < deadline:
        graph = stub.GetGraph(pb.GetGraphRequest(mesh="m", epsilon=eps), timeout=10)
        if graph.state == pb.GRAPH_STATE_READY:
            return graph.nodes
        if graph.state == pb.GRAPH_STATE_FAILED:
            raise RuntimeError(f"{name}: {graph.error}")
        time.sleep(0.2)
    raise RuntimeError(f"{name}: the graph was not ready in time")


def distance_p50(stub, pairs, eps):
    times, values = [], []
    for a, b in pairs:
        req = pb.DistanceRequest(mesh="m", epsilon=eps, pairs=[pb.PointPair(**{
            "from": pb.SurfacePoint(vertex=a), "to": pb.SurfacePoint(vertex=b)})])
        start = time.perf_counter()
        resp = stub.Distance(req, timeout=30)
        times.append(time.perf_counter() - start)
        values.append(resp.results[0].distance)
    return statistics.median(times), values


def field_p50(stub, sources, eps):
    times, values = [], []
    for s in sources:
        req = pb.DistanceFieldRequest(mesh="m", epsilon=eps, sources=[pb.SurfacePoint(vertex=s)])
        start = time.perf_counter()
        total = 0.0
        for chunk in stub.DistanceField(req, timeout=60):
            total += sum(chunk.values)
        times.append(time.perf_counter() - start)
        values.append(total)
    return statistics.median(times), values


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--before", required=True, help="geodesicd built before the change")
    ap.add_argument("--after", required=True, help="geodesicd built after the change")
    ap.add_argument("--mesh", default="armadillo.obj", help="file under ../shared/meshes")
    ap.add_argument("--eps", type=float, default=1e-3)
    ap.add_argument("--pairs", type=int, default=300, help="one-pair Distance calls per round")
    ap.add_argument("--fields", type=int, default=20, help="DistanceField calls per round")
    ap.add_argument("--rounds", type=int, default=7)
    args = ap.parse_args()
    mesh_root = os.path.join(SHARED, "meshes")
    work = tempfile.mkdtemp(prefix="daemon-ab-")
    graph_dir = os.path.join(work, "graphs")
    daemons = []
    try:
        after, after_stub = start(os.path.abspath(args.after), work, "after", mesh_root, graph_dir)
        daemons.append(after)
        vertices = ready(after_stub, args.mesh, args.eps, "after")
        before, before_stub = start(os.path.abspath(args.before), work, "before", mesh_root,
                                    graph_dir)
        daemons.append(before)
        ready(before_stub, args.mesh, args.eps, "before")
        stubs = {"before": before_stub, "after": after_stub}
        rng = random.Random(7)
        mesh_vertices = after_stub.GetMesh(pb.GetMeshRequest(name="m")).diagnostics.vertices
        assert mesh_vertices > 0 and vertices > 0
        rows = {k: {"distance": [], "field": []} for k in stubs}
        ratios = {"distance": [], "field": []}
        worst = 0.0
        for r in range(args.rounds):
            pairs = [(rng.randrange(mesh_vertices), rng.randrange(mesh_vertices))
                     for _ in range(args.pairs)]
            sources = [rng.randrange(mesh_vertices) for _ in range(args.fields)]
            order = ["before", "after"] if r % 2 == 0 else ["after", "before"]
            got = {}
            for name in order:
                d, dv = distance_p50(stubs[name], pairs, args.eps)
                f, fv = field_p50(stubs[name], sources, args.eps)
                rows[name]["distance"].append(d)
                rows[name]["field"].append(f)
                got[name] = dv + fv
            for kind in ratios:
                ratios[kind].append(rows["after"][kind][-1] / rows["before"][kind][-1])
            for x, y in zip(got["before"], got["after"]):
                worst = max(worst, abs(x - y) / max(abs(x), 1e-300))
            print(f"round {r + 1}: distance {ratios['distance'][-1]:.3f}, "
                  f"field {ratios['field'][-1]:.3f}", file=sys.stderr, flush=True)
        print(f"| call ({args.mesh}, ε = {args.eps:g}) | before p50 | after p50 | "
              f"after/before median (least-largest over {args.rounds} rounds) |")
        print("|---|---:|---:|---|")
        for kind, label in (("distance", "Distance, one vertex pair"),
                            ("field", "DistanceField, whole mesh")):
            b = statistics.median(rows["before"][kind]) * 1e3
            a = statistics.median(rows["after"][kind]) * 1e3
            q = ratios[kind]
            print(f"| {label} | {b:.3f} ms | {a:.3f} ms | {statistics.median(q):.3f} "
                  f"({min(q):.3f}-{max(q):.3f}) |")
        print(f"\nLargest relative difference between the two builds' answers: {worst:.1e}")
        return 0 if worst == 0 else 1
    finally:
        for d in daemons:
            daemon_ports.stop(d)


if __name__ == "__main__":
    sys.exit(main())
