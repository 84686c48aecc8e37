#!/usr/bin/python3
"""CancelGraph's contract (geodesic.proto, docs/daemon.md), against a real
daemon building igea.ply (134K vertices) at epsilon 1e-3, long enough to
cancel midway:

- CancelGraph returns at once; its answer's state may still be BUILDING
  (or QUEUED, LOADING, CANCELLED), never READY for a build midway.
- WatchGraph then ends in CANCELLED, within seconds.
- A query meanwhile gets FAILED_PRECONDITION ("being cancelled" or "was
  cancelled"), never UNAVAILABLE, even with a deadline shorter than the
  worker takes to stop; and after it, FAILED_PRECONDITION too.
- RequestGraph right after CancelGraph starts the graph anew at once
  (QUEUED or BUILDING, not CANCELLED), even while the cancelled worker stops.
- A ready graph has nothing to cancel: READY, and it answers queries.
- A graph never requested: NOT_FOUND.

Needs the shared meshes (../shared/meshes beside the source tree, or
GEODESIC_SHARED_DIR): without them it fails, it does not skip.

Usage: cancel_graph_test.py BUILD_BIN_DIR SOURCE_DIR
"""
import math
import os
import shutil
import sys
import tempfile
import time

BIN, SRC = sys.argv[1], sys.argv[2]
sys.path.insert(0, os.path.join(SRC, "client", "python"))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import grpc  # noqa: E402
from geodesic_client._stubs import pb, rpc  # noqa: E402
import daemon_ports  # noqa: E402
from checklist import Checklist  # noqa: E402

SHARED = os.environ.get("GEODESIC_SHARED_DIR", os.path.join(SRC, "..", "shared"))
MESHES = os.path.join(SHARED, "meshes")
SLOW = pb.GraphSelector(mesh="igea", epsilon=1e-3)  # about 10 s to build on 2 cores
FAST = pb.GraphSelector(mesh="eight", epsilon=0.05)
RUNNING = (pb.GRAPH_STATE_QUEUED, pb.GRAPH_STATE_BUILDING, pb.GRAPH_STATE_LOADING)
check = Checklist()


def name(state):
    return pb.GraphState.Name(state)


def building(stub, sel):
    """Requests `sel` and returns once its build is under way (progress > 0)."""
    stub.RequestGraph(pb.RequestGraphRequest(graph=sel), timeout=30)
    for g in stub.WatchGraph(pb.GetGraphRequest(graph=sel), timeout=120):
        if g.state == pb.GRAPH_STATE_BUILDING and g.progress > 0.02:
            return g
        if g.state not in RUNNING:
            raise RuntimeError(f"{sel.mesh} ended {name(g.state)} before it could be cancelled")
    raise RuntimeError("WatchGraph ended without the build under way")


def watch_to_end(stub, sel):
    """The states WatchGraph streams until it ends (at most 60 s)."""
    return [g.state for g in stub.WatchGraph(pb.GetGraphRequest(graph=sel), timeout=60)]


def query(stub, sel, timeout):
    pair = pb.PointPair(**{"from": pb.SurfacePoint(vertex=0), "to": pb.SurfacePoint(vertex=700)})
    try:
        r = stub.Distance(pb.DistanceRequest(graph=sel, pairs=[pair]), timeout=timeout)
        return "OK", r.results[0].distance
    except grpc.RpcError as e:
        return e.code().name, e.details()


def cancel_midway(stub):
    started = building(stub, SLOW)
    t = time.monotonic()
    answer = stub.CancelGraph(pb.CancelGraphRequest(graph=SLOW), timeout=10)
    took = time.monotonic() - t
    check(f"CancelGraph returns at once ({took:.3f} s, under 2 s)", took < 2, took)
    check(f"its answer's state is still running or cancelled, not READY: {name(answer.state)}",
          answer.state in RUNNING + (pb.GRAPH_STATE_CANCELLED,),
          (name(answer.state), started.progress))
    # 0.3 s: shorter than a build at this size takes to notice (0.1 to 0.4 s
    # measured), so the query may come while the worker still runs.
    code, detail = query(stub, SLOW, 0.3)
    check(f"a query while it stops: FAILED_PRECONDITION naming the cancel, never UNAVAILABLE "
          f"({detail[-40:] if code == 'FAILED_PRECONDITION' else code})",
          code == "FAILED_PRECONDITION" and "cancelled" in detail, (code, detail))
    t = time.monotonic()
    states = watch_to_end(stub, SLOW)
    check(f"WatchGraph ends in CANCELLED ({time.monotonic() - t:.2f} s after the answer)",
          states and states[-1] == pb.GRAPH_STATE_CANCELLED, [name(s) for s in states])
    g = stub.GetGraph(pb.GetGraphRequest(graph=SLOW), timeout=10)
    check("GetGraph says CANCELLED", g.state == pb.GRAPH_STATE_CANCELLED, name(g.state))
    code, detail = query(stub, SLOW, 10)
    check("a query afterwards: FAILED_PRECONDITION, request it again",
          code == "FAILED_PRECONDITION" and "request it again" in detail, (code, detail))


def request_again(stub):
    building(stub, SLOW)
    stub.CancelGraph(pb.CancelGraphRequest(graph=SLOW), timeout=10)
    again = stub.RequestGraph(pb.RequestGraphRequest(graph=SLOW), timeout=10)
    check(f"RequestGraph right after CancelGraph starts anew: {name(again.state)}",
          again.state in (pb.GRAPH_STATE_QUEUED, pb.GRAPH_STATE_BUILDING), name(again.state))
    # The new operation is not cancelled by the old one's stop.
    time.sleep(1)
    g = stub.GetGraph(pb.GetGraphRequest(graph=SLOW), timeout=10)
    check(f"and it goes on after the cancelled worker stopped: {name(g.state)}",
          g.state in RUNNING + (pb.GRAPH_STATE_READY,), name(g.state))
    stub.CancelGraph(pb.CancelGraphRequest(graph=SLOW), timeout=10)
    states = watch_to_end(stub, SLOW)
    check("cancelled again, it ends CANCELLED (or READY had it finished)",
          states and states[-1] in (pb.GRAPH_STATE_CANCELLED, pb.GRAPH_STATE_READY),
          [name(s) for s in states])


def ready_and_unknown(stub):
    stub.RequestGraph(pb.RequestGraphRequest(graph=FAST), timeout=30)
    states = watch_to_end(stub, FAST)
    check("a small graph becomes READY", states[-1:] == [pb.GRAPH_STATE_READY],
          [name(s) for s in states])
    g = stub.CancelGraph(pb.CancelGraphRequest(graph=FAST), timeout=10)
    check("CancelGraph of a ready graph: READY, nothing cancelled",
          g.state == pb.GRAPH_STATE_READY, name(g.state))
    code, d = query(stub, FAST, 30)
    check("and it still answers queries", code == "OK" and math.isfinite(d), (code, d))
    try:
        stub.CancelGraph(pb.CancelGraphRequest(graph=pb.GraphSelector(mesh="eight", epsilon=0.3)),
                         timeout=10)
        check("CancelGraph of a graph never requested: NOT_FOUND", False, "answered")
    except grpc.RpcError as e:
        check("CancelGraph of a graph never requested: NOT_FOUND",
              e.code() == grpc.StatusCode.NOT_FOUND, e.code())


def main():
    if not os.path.isfile(os.path.join(MESHES, "igea.ply")):
        raise RuntimeError(f"the shared meshes are missing: {MESHES}")
    work = tempfile.mkdtemp(prefix="cancel_graph.")
    try:
        log = open(os.path.join(work, "daemon.log"), "w")
        daemon, ports = daemon_ports.start_daemon(
            BIN, work, ["--mesh-root", MESHES, "--graph-dir", os.path.join(work, "graphs"),
                        "--no-sample", "--log-level", "warning"], stderr=log)
        channel = grpc.insecure_channel(f"127.0.0.1:{ports['grpc']}")
        stub = rpc.GeodesicStub(channel)
        for mesh, path in (("igea", "igea.ply"), ("eight", "eight.off")):
            stub.RegisterMesh(pb.RegisterMeshRequest(name=mesh, path=path), timeout=120)
        cancel_midway(stub)
        request_again(stub)
        ready_and_unknown(stub)
        channel.close()
        check("the daemon stops cleanly", daemon_ports.stop(daemon, timeout=60) == 0)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    check.finish()


if __name__ == "__main__":
    main()
