#!/usr/bin/python3
"""Streams a client never reads, or never finishes sending, take nothing from the others (#55).

Beside a well-behaved client sending light queries:
- (a) two MatrixRows of every pair of the bundled mesh that nobody reads, and (b) two
  DistanceField streams likewise: the light queries are answered (at least 18 of 20, p99
  under a second), since a stream gives its query slot back while it waits for its client;
  read afterwards, each stream still delivers its whole answer;
- (c) more GetGeometry streams than --max-streams from one client, none read: past its share
  (--max-streams-per-client) they are refused at once naming it, another client still opens
  its own, past them all a stream is refused naming --max-streams, listing and queries keep
  answering, and the capacity health status says NOT_SERVING while every stream slot is taken;
- (f) a unary Matrix answer whose client stopped reading is cancelled after --idle-seconds,
  giving back the thread that was sending it;
- (e) forty registrations of a large mesh at once from one client: past its share of the
  changes in progress (registrations, unloads, graph requests) they are refused at once, and
  listing and queries keep their threads;
- (d) an upload that sends one message and then nothing, and a GetGeometry nobody reads, are
  closed after --idle-seconds and their slots given back, while an upload sending slowly but
  steadily is not.

The unread streams' clients turn gRPC's BDP probing off, so that their flow-control window
stays at its initial size and a modest answer fills it: the daemon must not depend on how
much a client happens to buffer. Meshes: the bundled data/spot.obj and a grid made here.
Every daemon listens on 127.0.0.1 port 0, and every wait is bounded.

Usage: fairness_streams_test.py BUILD_BIN_DIR SOURCE_DIR
"""
import hashlib
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request

BIN, SRC = sys.argv[1], sys.argv[2]
sys.path.insert(0, os.path.join(SRC, "client", "python"))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import grpc  # noqa: E402
import numpy as np  # noqa: E402
from geodesic_client import Client  # noqa: E402
from geodesic_client._stubs import pb, rpc  # noqa: E402
import daemon_ports  # noqa: E402
from checklist import Checklist  # noqa: E402
from daemon_ports import start_daemon  # noqa: E402
from fairness_clients import (SPOT_VERTICES, as_client, light_queries, p99,  # noqa: E402
                              refused_streams, unread_streams, wait_ready)

GRID = 100  # the grid mesh's side in vertices: its field and geometry outgrow a 64 KiB window
GRID_EPS = 0.05  # coarse: the grid's graph builds in a moment
BIG_GRID = 400  # (e)'s mesh: a moment to read, so registrations queue on its name
SERVING, NOT_SERVING = 1, 2  # grpc.health.v1.HealthCheckResponse.ServingStatus

check = Checklist()
work = tempfile.mkdtemp(prefix="fairness-streams-")


# The clients of cases (c) and (e), a token each (their daemons require one):
# clients on one host are one client unless their tokens tell them apart.
# Calls naming none are MAIN's.
MAIN = "main"
TOKENS = [MAIN, "flood", "other", "third", "registrar"]


def serve(name, *extra, tokens=None):
    log = open(os.path.join(work, f"{name}.log"), "w")
    daemon, ports = start_daemon(BIN, os.path.join(work, name),
                                 ["--graph-dir", os.path.join(work, name, "graphs"),
                                  "--log-level", "info", *extra],
                                 stderr=log, metrics=True, tokens=tokens)
    return daemon, ports, log.name


def main_channel(address):
    """A channel whose calls are MAIN's unless they name another token."""
    return daemon_ports.authed(grpc.insecure_channel(address), MAIN)


def metrics(port):
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5) as r:
        text = r.read().decode()
    return {m.group(1): float(m.group(2))
            for m in re.finditer(r"^(geodesicd_\w+) (\S+)$", text, re.M)}


def health_check(channel):
    """grpc.health.v1.Health/Check with its one-field messages encoded by hand (Debian's
    python3-grpcio has no grpc_health module)."""
    def encode(service):
        data = service.encode()
        return b"\x0a" + bytes([len(data)]) + data

    def decode(data):
        return data[1] if len(data) >= 2 and data[0] == 0x08 else 0

    return channel.unary_unary("/grpc.health.v1.Health/Check", request_serializer=encode,
                               response_deserializer=decode)


def grid(side):
    """A side x side wavy grid: its vertices and faces."""
    xs, ys = np.meshgrid(np.arange(side, dtype=float), np.arange(side, dtype=float))
    vertices = np.stack([xs.ravel(), ys.ravel(), 0.2 * np.sin(xs.ravel() / 3)], axis=1)
    i, j = np.meshgrid(np.arange(side - 1), np.arange(side - 1), indexing="ij")
    a, b = (i * side + j).ravel(), (i * side + j + 1).ravel()
    c, d = ((i + 1) * side + j + 1).ravel(), ((i + 1) * side + j).ravel()
    return vertices, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def upload_grid(address, stub, graph=True):
    """A GRID x GRID wavy grid, its graph at GRID_EPS built if `graph`."""
    vertices, faces = grid(GRID)
    with Client(address, timeout=60, token=MAIN) as client:
        client.upload_mesh("grid", vertices=vertices, faces=faces)
    if not graph:
        return True
    stub.RequestGraph(pb.RequestGraphRequest(mesh="grid", epsilon=GRID_EPS), timeout=10)
    return wait_ready(stub, "grid", GRID_EPS)


def check_light(name, latencies, errors):
    check(f"{name}: at least 18 of 20 light queries answered", len(latencies) >= 18,
          f"{len(latencies)} answered; errors {errors[:3]}")
    check(f"{name}: p99 of the light queries under 1 s", p99(latencies) < 1.0,
          f"p99 {p99(latencies):.3f} s")


def drain(streams, seconds):
    """Reads every stream to its end: each one's messages, or its error."""
    results = [None] * len(streams)

    def read(k):
        try:
            results[k] = list(streams[k])
        except grpc.RpcError as e:
            results[k] = f"{e.code().name}: {e.details()}"

    threads = [threading.Thread(target=read, args=(k,)) for k in range(len(streams))]
    for t in threads:
        t.start()
    deadline = time.time() + seconds
    for t in threads:
        t.join(timeout=max(0.1, deadline - time.time()))
    return results


def case_unread_queries(address, stub):
    # (a) every pair of spot at float64: far more than any window.
    matrix = pb.MatrixRequest(mesh="spot", all_sources=True, all_targets=True,
                              dtype=pb.MATRIX_DTYPE_FLOAT64)
    channels, streams = unread_streams(address, lambda s, r: s.MatrixRows(r, timeout=60),
                                       [matrix, matrix])
    time.sleep(1.0)  # their first blocks computed, their windows full
    check_light("(a) unread MatrixRows", *light_queries(stub))
    results = drain(streams, 40)
    rows = [sum(c.rows for c in r) if isinstance(r, list) else r for r in results]
    check("(a) each MatrixRows, read afterwards, delivers every row",
          rows == [SPOT_VERTICES] * 2, rows)
    for ch in channels:
        ch.close()

    # (b) fields of the grid, each larger than a window.
    field = pb.DistanceFieldRequest(mesh="grid", epsilon=GRID_EPS,
                                    sources=[pb.SurfacePoint(vertex=0)])
    channels, streams = unread_streams(address, lambda s, r: s.DistanceField(r, timeout=60),
                                       [field, field])
    time.sleep(1.0)
    check_light("(b) unread DistanceField", *light_queries(stub))
    results = drain(streams, 30)
    values = [sum(len(c.values) for c in r) if isinstance(r, list) else r for r in results]
    check("(b) each DistanceField, read afterwards, delivers every value",
          values == [GRID * GRID] * 2, values)
    for ch in channels:
        ch.close()


def case_unread_geometry(address, stub, channel, max_streams):
    # (c) ten times --max-streams from one client, on a small thread quota: before streams
    # were counted, these took every gRPC thread. The client gets its share (half of
    # --max-streams); a second client still opens its own; past them, every stream is refused.
    share = max_streams // 2
    n = 10 * max_streams
    channels, streams = unread_streams(
        address, lambda s, r: s.GetGeometry(r, timeout=30, metadata=as_client("flood")),
        [pb.GetMeshRequest(name="grid")] * n)
    refused = refused_streams(streams, n - share)
    codes = {s.code() for s in refused}
    details = [s.details() for s in refused]
    check("(c) one client's streams past its share are refused at once",
          len(refused) == n - share, f"{len(refused)} of {n} ended")
    check("(c) refused RESOURCE_EXHAUSTED", codes == {grpc.StatusCode.RESOURCE_EXHAUSTED}, codes)
    check("(c) the refusal names --max-streams-per-client",
          details and all("--max-streams-per-client" in d for d in details), details[:1])
    other_channels, others = unread_streams(
        address, lambda s, r: s.GetGeometry(r, timeout=30, metadata=as_client("other")),
        [pb.GetMeshRequest(name="grid")] * share)
    channels += other_channels
    streams += others
    check("(c) another client opens its share beside the first",
          not refused_streams(others, 1, seconds=1), [s.details() for s in others if s.done()])
    third_channels, third = unread_streams(
        address, lambda s, r: s.GetGeometry(r, timeout=30, metadata=as_client("third")),
        [pb.GetMeshRequest(name="grid")])
    channels += third_channels
    streams += third
    ended = refused_streams(third, 1)
    check("(c) with every slot taken a stream is refused naming --max-streams",
          len(ended) == 1 and ended[0].code() == grpc.StatusCode.RESOURCE_EXHAUSTED and
          "(--max-streams)" in ended[0].details(), [s.details() for s in ended])
    health = health_check(channel)
    capacity = None
    try:
        capacity = health("geodesic.v1.Geodesic/capacity", timeout=3)
    except grpc.RpcError as e:
        capacity = e.code().name
    check("(c) capacity health says NOT_SERVING while every stream slot is taken",
          capacity == NOT_SERVING, capacity)

    def listing():
        names = {m.name for m in stub.ListMeshes(pb.ListMeshesRequest(), timeout=3).meshes}
        assert "grid" in names, names
        stub.GetMesh(pb.GetMeshRequest(name="spot"), timeout=3)
    check_light("(c) unread GetGeometry (queries, listing, get)",
                *light_queries(stub, also=listing))
    for s in streams:
        s.cancel()
    for ch in channels:
        ch.close()


def ended_within(call, start, seconds):
    """How long after `start` the call ended, or None if it still runs after `seconds`."""
    while time.monotonic() - start < seconds:
        if call.done():
            return time.monotonic() - start
        time.sleep(0.05)
    return None


# A client that asks for a unary answer and then stops (a stopped or hung process): it reads
# nothing, so its connection's flow-control window stays shut.
STOPPED_CLIENT = """
import sys, time
sys.path.insert(0, sys.argv[2])
import grpc
from geodesic_client._stubs import pb, rpc
channel = grpc.insecure_channel(sys.argv[1], options=[("grpc.http2.bdp_probe", 0)])
grpc.channel_ready_future(channel).result(timeout=10)
req = pb.MatrixRequest(exact=True, all_targets=True)
req.graph.mesh = sys.argv[3]
for v in range(16):
    req.sources.add().vertex = 150 * v
call = rpc.GeodesicStub(channel).Matrix.future(req, timeout=120)
print("asked", flush=True)
time.sleep(120)
"""


def case_unread_answer(address, metrics_port, log, idle):
    # (f) a unary answer (16 exact rows of spot, 375 KB: more than a flow-control window)
    # whose client stopped as the server computed it: the synchronous server's thread waits
    # until the answer is taken, so it is cancelled after --idle-seconds like a stream's
    # message.
    before = metrics(metrics_port).get("geodesicd_streams_idle_closed_total", 0)
    client = subprocess.Popen([sys.executable, "-c", STOPPED_CLIENT, address,
                               os.path.join(SRC, "client", "python"), "spot"],
                              stdout=subprocess.PIPE, text=True)
    try:
        asked = client.stdout.readline().strip() == "asked"
        # Stopped while the server computes its rows: it never takes the answer.
        deadline, computing = time.monotonic() + 20, False
        while asked and not computing and time.monotonic() < deadline:
            computing = metrics(metrics_port).get("geodesicd_queries_running", 0) > 0
        client.send_signal(signal.SIGSTOP)
        check("(f) the client asked, and was stopped while its answer was computed",
              asked and computing)
        start, closed = time.monotonic(), False
        while not closed and time.monotonic() - start < idle + 8:
            closed = metrics(metrics_port).get("geodesicd_streams_idle_closed_total", 0) > before
            time.sleep(0.2)
        check("(f) a unary answer nobody takes is cancelled after --idle-seconds", closed,
              f"not after {idle + 8} s")
        with open(log) as f:
            check("(f) logged as the Matrix answer",
                  "the answer of /geodesic.v1.Geodesic/Matrix" in f.read())
    finally:
        client.kill()
        client.wait(timeout=10)


def case_registrations(address, stub, mesh_root):
    # (e) one client asks to register a large mesh forty times at once: each waits for the
    # name, on a thread of its own. Past the client's share of the changes in progress they are
    # refused at once, so listing and queries keep their threads (before, these forty took
    # every thread of a small quota: "Server Threadpool Exhausted").
    vertices, faces = grid(BIG_GRID)
    with open(os.path.join(mesh_root, "big.obj"), "w") as f:
        f.write("".join(f"v {x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in vertices))
        f.write("".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces))
    n = 40
    channels = [grpc.insecure_channel(address) for _ in range(n)]
    calls = [rpc.GeodesicStub(ch).RegisterMesh.future(
        pb.RegisterMeshRequest(name="big", path="big.obj"), timeout=60,
        metadata=as_client("registrar")) for ch in channels]

    def listing():
        stub.ListMeshes(pb.ListMeshesRequest(), timeout=3)
    # While the registrations wait on the name, not after.
    light = light_queries(stub, also=listing)
    refused = refused_streams(calls, n - 4, seconds=5)
    details = [c.details() for c in refused if c.code() == grpc.StatusCode.RESOURCE_EXHAUSTED]
    check("(e) registrations past the client's share of changes are refused at once",
          len(details) >= n - 4,
          f"{len(details)} of {n} refused; {[c.details() for c in refused][:2]}")
    check("(e) the refusal names the changes in progress",
          details and all("registrations, unloads and graph requests" in d for d in details),
          details[:1])
    check_light("(e) forty registrations at once (queries, listing)", *light)
    for c in calls:
        c.exception(timeout=60)  # every call ended, either way
    admitted = [c for c in calls if c.code() == grpc.StatusCode.OK]
    others = [f"{c.code().name}: {c.details()}" for c in calls
              if c.code() not in (grpc.StatusCode.OK, grpc.StatusCode.RESOURCE_EXHAUSTED)]
    check("(e) the admitted registrations succeed, the others were refused",
          admitted and not others and
          all(c.result().diagnostics.vertices == BIG_GRID ** 2 for c in admitted),
          f"{len(admitted)} registered; {others[:2]}")
    for ch in channels:
        ch.close()


def case_idle(address, stub, metrics_port, log, idle):
    # (d) a first message, then nothing; and an answer nobody reads.
    payload = b"v 0 0 0\n" * 1000
    release = threading.Event()

    def one_then_nothing():
        yield pb.UploadMeshRequest(name="idle", format="obj", total_bytes=len(payload),
                                   sha256="0" * 64, data=payload[:8])
        release.wait(60)

    with open(os.path.join(SRC, "data", "spot.obj"), "rb") as f:
        spot = f.read()

    def steady():
        # Four parts, each well within --idle-seconds of the last.
        step = len(spot) // 4 + 1
        for start in range(0, len(spot), step):
            if start:
                time.sleep(idle * 0.4)
            yield pb.UploadMeshRequest(
                data=spot[start:start + step],
                **(dict(name="steady", format="obj", total_bytes=len(spot),
                        sha256=hashlib.sha256(spot).hexdigest()) if not start else {}))

    channels = []
    try:
        start = time.monotonic()
        idle_call = stub.UploadMesh.future(one_then_nothing(), timeout=60)
        steady_call = stub.UploadMesh.future(steady(), timeout=60)
        channels, (unread,) = unread_streams(address, lambda s, r: s.GetGeometry(r, timeout=60),
                                             [pb.GetMeshRequest(name="grid")])
        ended = ended_within(idle_call, start, idle + 6)
        check("(d) an upload idle for --idle-seconds is closed", ended is not None,
              f"still open after {idle + 6} s")
        check("(d) ... not before --idle-seconds", ended is None or ended >= idle * 0.9, ended)
        if ended is not None:
            check("(d) ... ending the client's call with an error",
                  idle_call.exception() is not None, idle_call)
        try:
            steady_error = None if steady_call.result(timeout=idle * 4 + 10).name == "steady" \
                else "another mesh"
        except grpc.RpcError as e:
            steady_error = f"{e.code().name}: {e.details()}"
        check("(d) an upload sending steadily, slower than --idle-seconds in all, is registered",
              steady_error is None, steady_error)
        deadline = time.time() + 5
        while time.time() < deadline and metrics(metrics_port).get("geodesicd_streams_open"):
            time.sleep(0.1)
        values = metrics(metrics_port)
        check("(d) its stream slot is given back", values.get("geodesicd_streams_open") == 0,
              values.get("geodesicd_streams_open"))
        check("(d) both, and only they, counted as closed for idling",
              values.get("geodesicd_streams_idle_closed_total") == 2,
              values.get("geodesicd_streams_idle_closed_total"))
        # Its client sees the end once it reads what arrived before it.
        (geometry,) = drain([unread], 10)
        check("(d) a GetGeometry nobody reads is closed after --idle-seconds",
              isinstance(geometry, str) and geometry.startswith("CANCELLED"),
              geometry if isinstance(geometry, str) else f"{len(geometry)} chunks, no error")
        with open(log) as f:
            check("(d) logged", "stream_idle_closed" in f.read())
    finally:
        release.set()
        for ch in channels:
            ch.close()


def main():
    started = time.monotonic()
    # (a), (b): two query threads, as on a two-core machine by default.
    daemon, ports, _ = serve("queries", "--query-threads", "2")
    address = f"127.0.0.1:{ports['grpc']}"
    with main_channel(address) as channel:
        stub = rpc.GeodesicStub(channel)
        if check("spot's graph ready", wait_ready(stub, "spot")) and \
                check("the grid uploaded, its graph ready", upload_grid(address, stub)):
            case_unread_queries(address, stub)
    daemon_ports.stop(daemon)

    # (c): a small thread quota (--max-inflight + --max-streams + the control threads).
    max_streams = 4
    daemon, ports, _ = serve("geometry", "--query-threads", "2", "--max-inflight", "4",
                             "--max-streams", str(max_streams), tokens=TOKENS)
    address = f"127.0.0.1:{ports['grpc']}"
    with main_channel(address) as channel:
        stub = rpc.GeodesicStub(channel)
        if check("(c) spot's graph ready", wait_ready(stub, "spot")) and \
                check("(c) the grid uploaded", upload_grid(address, stub)):
            case_unread_geometry(address, stub, channel, max_streams)
    daemon_ports.stop(daemon)

    # (e): the same small thread quota, meshes registered from a root.
    mesh_root = os.path.join(work, "meshes")
    os.makedirs(mesh_root, exist_ok=True)
    daemon, ports, _ = serve("registrations", "--max-inflight", "4", "--max-streams", "4",
                             "--mesh-root", mesh_root, tokens=TOKENS)
    address = f"127.0.0.1:{ports['grpc']}"
    with main_channel(address) as channel:
        stub = rpc.GeodesicStub(channel)
        if check("(e) spot's graph ready", wait_ready(stub, "spot")):
            case_registrations(address, stub, mesh_root)
    daemon_ports.stop(daemon)

    # (f): a short --idle-seconds, the bundled mesh.
    idle = 2
    daemon, ports, log = serve("answers", "--idle-seconds", str(idle))
    address = f"127.0.0.1:{ports['grpc']}"
    with main_channel(address) as channel:
        stub = rpc.GeodesicStub(channel)
        if check("(f) spot's graph ready", wait_ready(stub, "spot")):
            case_unread_answer(address, ports["metrics"], log, idle)
    daemon_ports.stop(daemon)

    # (d): a short --idle-seconds.
    daemon, ports, log = serve("idle", "--no-sample", "--idle-seconds", str(idle))
    address = f"127.0.0.1:{ports['grpc']}"
    with main_channel(address) as channel:
        stub = rpc.GeodesicStub(channel)
        if check("(d) the grid uploaded", upload_grid(address, stub, graph=False)):
            case_idle(address, stub, ports["metrics"], log, idle)
    daemon_ports.stop(daemon)
    print(f"{time.monotonic() - started:.1f} s")


if __name__ == "__main__":
    try:
        main()
    except RuntimeError as e:  # a daemon that would not start
        check("daemon started", False, str(e)[-2000:])
    finally:
        shutil.rmtree(work, ignore_errors=True)
    check.finish()
