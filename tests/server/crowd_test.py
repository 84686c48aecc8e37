#!/usr/bin/python3
"""A crowd of clients against a daemon on default flags: the documented limits are the real ones.

- 64 concurrent clients (--max-inflight's default; each with a token of its own) doing pairs,
  fields and small matrices get no error at all, while 16 WatchGraph streams are held open on a building graph and listing,
  GetGraph, CancelGraph and health each answer within a second;
- past the limit (queries admitted and as many waiting for a slot), the only error is a clean
  RESOURCE_EXHAUSTED "server overloaded" with a
  retry-after-ms hint;
- afterwards the admission gauges on /metrics are back to 0;
- a matrix whose answer cannot fit a message is refused at once, naming its size;
- a 10 KB mesh name comes back cut, in an error that fits the metadata;
- under --memory-limit, a flood of large matrices keeps resident memory within the limit plus
  the daemon's idle resident memory at start.

Default flags but --min-epsilon 1e-6 and a --mesh-root, for the watched graph's slow build.

Usage: crowd_test.py BUILD_BIN_DIR SOURCE_DIR [SECONDS]
"""
import functools
import os
import shutil
import sys
import tempfile
import threading
import time
import unittest

BIN, SRC = sys.argv[1], sys.argv[2]
SECONDS = float(sys.argv[3]) if len(sys.argv) > 3 else 12
sys.path.insert(0, os.path.join(SRC, "client", "python"))
import grpc  # noqa: E402
from geodesic_client import Client  # noqa: E402
from geodesic_client._stubs import pb, rpc  # noqa: E402
import daemon_ports  # noqa: E402
from daemon_ports import metrics, rss_bytes, start_daemon  # noqa: E402
from geodesicd_runner import read_obj  # noqa: E402
sys.path.insert(0, os.path.join(SRC, "bench"))
from subdivide_mesh import subdivide, write_ply  # noqa: E402

SPOT_VERTICES = 2930
# The watches below must stay open for the whole crowd, on any machine: the
# watched graph is spot subdivided twice, at an epsilon whose build takes
# far longer than the crowd. Spot itself at this epsilon once finished
# within the crowd on a faster machine.
BUILDING_EPS = 5e-6
FINE_SUBDIVISIONS = 2

GAUGES = ("geodesicd_queue_depth", "geodesicd_queries_running", "geodesicd_queries_waiting",
          "geodesicd_streams_open", "geodesicd_reserved_bytes")


def write_fine_spot(path):
    """spot.obj subdivided FINE_SUBDIVISIONS times, as a PLY at `path`."""
    vertices, faces = read_obj(os.path.join(SRC, "data", "spot.obj"))
    for _ in range(FINE_SUBDIVISIONS):
        vertices, faces = subdivide(vertices, faces)
    write_ply(path, vertices, faces)


SERVING, NOT_SERVING = 1, 2  # grpc.health.v1.HealthCheckResponse.ServingStatus


def health_check(channel):
    """grpc.health.v1.Health/Check, its two one-field messages encoded by hand (Debian's
    python3-grpcio has no grpc_health module): the service's serving status."""
    def encode(service):
        data = service.encode()
        assert len(data) < 128
        return b"\x0a" + bytes([len(data)]) + data

    def decode(data):
        return data[1] if len(data) >= 2 and data[0] == 0x08 else 0

    return channel.unary_unary("/grpc.health.v1.Health/Check", request_serializer=encode,
                               response_deserializer=decode)


def wait_for_spot(stub):
    """The daemon requests spot's graph just after it starts listening, then builds it."""
    deadline = time.time() + 60
    while True:
        try:
            if stub.GetGraph(pb.GetGraphRequest(mesh="spot"), timeout=5).state == \
                    pb.GRAPH_STATE_READY:
                return
        except grpc.RpcError as e:
            if e.code() != grpc.StatusCode.NOT_FOUND:
                raise
        assert time.time() < deadline, "spot's graph was not ready within 60 s"
        time.sleep(0.1)


def vertex(v):
    return pb.SurfacePoint(vertex=v)


class AsClient:
    """A stub whose calls carry a bearer token of their own: a daemon that
    requires tokens tells clients apart by them (else by address, which every
    thread here shares). A daemon that requires none ignores them."""

    def __init__(self, stub, token):
        self.stub, self.metadata = stub, [("authorization", f"Bearer {token}")]

    def __getattr__(self, name):
        return functools.partial(getattr(self.stub, name), metadata=self.metadata)


class Crowd:
    """Client threads calling until `stop`, tallying answers by code."""

    def __init__(self, port, clients, ops, stop):
        self.errors, self.counts, self.lock = [], {}, threading.Lock()
        self.threads = [threading.Thread(target=self.client, args=(port, i, ops, stop))
                        for i in range(clients)]

    def client(self, port, i, ops, stop):
        with grpc.insecure_channel(f"127.0.0.1:{port}", options=[
                ("grpc.max_receive_message_length", 64 << 20)]) as channel:
            stub = AsClient(rpc.GeodesicStub(channel), f"crowd-{i}")
            n = 0
            while not stop.is_set():
                op = ops[(i + n) % len(ops)]
                n += 1
                try:
                    op(stub, i * 7919 + n)
                    code = "OK"
                except grpc.RpcError as e:
                    code = e.code().name
                    trailing = dict(e.trailing_metadata() or ())
                    with self.lock:
                        self.errors.append((code, e.details(), trailing.get("retry-after-ms")))
                    if code == "RESOURCE_EXHAUSTED":
                        time.sleep(int(trailing.get("retry-after-ms", "10")) / 1e3)
                with self.lock:
                    self.counts[code] = self.counts.get(code, 0) + 1

    def run(self):
        for t in self.threads:
            t.start()

    def join(self):
        deadline = time.time() + 60  # every call has a deadline of 60 s
        for t in self.threads:
            t.join(timeout=max(0.1, deadline - time.time()))
            assert not t.is_alive(), "a client thread hung"


def pairs(stub, seed):
    req = pb.DistanceRequest(mesh="spot", pairs=[
        pb.PointPair(**{"from": vertex((seed + k) % SPOT_VERTICES),
                        "to": vertex((seed * 31 + k * 97) % SPOT_VERTICES)}) for k in range(8)])
    resp = stub.Distance(req, timeout=60)
    assert len(resp.results) == 8


def field(stub, seed):
    req = pb.DistanceFieldRequest(mesh="spot", sources=[vertex(seed % SPOT_VERTICES)])
    total = sum(len(c.values) for c in stub.DistanceField(req, timeout=60))
    assert total == SPOT_VERTICES, total


def matrix(stub, seed):
    req = pb.MatrixRequest(mesh="spot",
                           sources=[vertex((seed + k) % SPOT_VERTICES) for k in range(3)],
                           targets=[vertex((seed * 13 + k) % SPOT_VERTICES) for k in range(40)])
    resp = stub.Matrix(req, timeout=60)
    assert len(resp.distances) == 120


class DefaultFlagsTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.work = tempfile.mkdtemp()
        write_fine_spot(os.path.join(cls.work, "spot_fine.ply"))
        cls.daemon, ports = start_daemon(
            BIN, cls.work, ["--graph-dir", f"{cls.work}/graphs", "--log-level", "warning",
                            # The watched graph must build for the whole crowd.
                            "--min-epsilon", "1e-6", "--mesh-root", cls.work],
            metrics=True, tokens=["main"] + [f"crowd-{i}" for i in range(160)])
        cls.port, cls.metrics_port = ports["grpc"], ports["metrics"]
        cls.channel = daemon_ports.authed(grpc.insecure_channel(f"127.0.0.1:{cls.port}"), "main")
        cls.stub = rpc.GeodesicStub(cls.channel)
        cls.health = health_check(cls.channel)
        wait_for_spot(cls.stub)
        cls.stub.RegisterMesh(pb.RegisterMeshRequest(name="spot_fine", path="spot_fine.ply"),
                              timeout=60)

    @classmethod
    def tearDownClass(cls):
        cls.channel.close()
        daemon_ports.stop(cls.daemon)
        shutil.rmtree(cls.work)

    def timed(self, what, call):
        start = time.monotonic()
        result = call()
        elapsed = time.monotonic() - start
        self.assertLess(elapsed, 1.0, f"{what} took {elapsed:.2f} s")
        return result

    def test_1_crowd_at_the_limits_is_answered_and_control_calls_stay_fast(self):
        building = dict(mesh="spot_fine", epsilon=BUILDING_EPS)
        self.stub.RequestGraph(pb.RequestGraphRequest(**building), timeout=10)
        watches = [self.stub.WatchGraph(pb.GetGraphRequest(**building), timeout=60)
                   for _ in range(16)]
        watched = [[] for _ in watches]

        def drain(w, states):
            try:
                for g in w:
                    states.append(g.state)
            except grpc.RpcError as e:
                states.append(e.code().name)

        watchers = [threading.Thread(target=drain, args=(w, states))
                    for w, states in zip(watches, watched)]
        for t in watchers:
            t.start()
        stop = threading.Event()
        crowd = Crowd(self.port, 64, [pairs, field, matrix], stop)
        crowd.run()
        control = 0
        try:
            end = time.time() + SECONDS
            while time.time() < end:
                self.timed("ListMeshes", lambda: self.stub.ListMeshes(pb.ListMeshesRequest(),
                                                                      timeout=5))
                g = self.timed("GetGraph", lambda: self.stub.GetGraph(
                    pb.GetGraphRequest(**building), timeout=5))
                self.assertNotIn(g.state, (pb.GRAPH_STATE_READY, pb.GRAPH_STATE_FAILED),
                                 "the watched graph finished early: the watches did not stay "
                                 "open")
                for service in ("", "geodesic.v1.Geodesic"):
                    r = self.timed("health", lambda: self.health(service, timeout=5))
                    self.assertEqual(r, SERVING)
                control += 1
                time.sleep(0.1)
            # The watches, and the crowd's fields, which are streams too.
            self.assertGreaterEqual(metrics(self.metrics_port)["geodesicd_streams_open"], 16)
            self.timed("CancelGraph", lambda: self.stub.CancelGraph(
                pb.CancelGraphRequest(**building), timeout=5))
        finally:
            stop.set()
            crowd.join()
            self.stub.CancelGraph(pb.CancelGraphRequest(**building), timeout=30)
            deadline = time.time() + 30
            for t in watchers:
                t.join(timeout=max(0.1, deadline - time.time()))
        self.assertEqual(crowd.errors[:5], [], f"answers: {crowd.counts}")
        self.assertGreater(crowd.counts.get("OK", 0), 64)
        self.assertGreater(control, 5)
        # Each watch saw the build's progress, then its end.
        self.assertEqual([states[-1] for states in watched], [pb.GRAPH_STATE_CANCELLED] * 16)

    def test_2_past_the_limit_the_only_error_is_a_clean_overload(self):
        stop = threading.Event()
        # Past --max-inflight and the as many again that may wait for a slot.
        crowd = Crowd(self.port, 160, [pairs, field, matrix], stop)
        crowd.run()
        time.sleep(min(SECONDS, 6))
        capacity = self.health("geodesic.v1.Geodesic/capacity", timeout=5)
        stop.set()
        crowd.join()
        self.assertEqual(capacity, NOT_SERVING)
        self.assertGreater(crowd.counts.get("OK", 0), 64)
        self.assertGreater(crowd.counts.get("RESOURCE_EXHAUSTED", 0), 0, crowd.counts)
        for code, details, retry_after in crowd.errors:
            self.assertEqual(code, "RESOURCE_EXHAUSTED", details)
            self.assertTrue(details.startswith("server overloaded"), details)
            self.assertIsNotNone(retry_after, details)
            self.assertGreater(int(retry_after), 0)

    def test_3_gauges_return_to_zero_when_idle(self):
        deadline = time.time() + 10
        while True:
            values = metrics(self.metrics_port)
            busy = {g: values.get(g) for g in GAUGES if values.get(g) != 0}
            if not busy:
                break
            self.assertLess(time.time(), deadline, f"gauges not back to 0: {busy}")
            time.sleep(0.2)
        deadline = time.time() + 5
        while self.health("geodesic.v1.Geodesic/capacity", timeout=5) != SERVING:
            self.assertLess(time.time(), deadline, "still reported overloaded when idle")
            time.sleep(0.2)

    def test_4_a_matrix_too_large_for_a_message_is_refused_at_once(self):
        req = pb.MatrixRequest(mesh="spot", sources=[vertex(v) for v in range(1024)],
                               targets=[vertex(v % SPOT_VERTICES) for v in range(10000)])
        start = time.monotonic()
        with self.assertRaises(grpc.RpcError) as e:
            self.stub.Matrix(req, timeout=60)
        self.assertLess(time.monotonic() - start, 1.0)
        self.assertEqual(e.exception.code(), grpc.StatusCode.RESOURCE_EXHAUSTED)
        details = e.exception.details()
        self.assertIn("1024 x 10000", details)
        self.assertRegex(details, r"\d{8,} bytes")
        self.assertIn("row blocks", details)
        # A client that assumes a larger cap than the server's tiles the matrix again in row
        # blocks the server accepts.
        sources, targets = list(range(1024)), [v % SPOT_VERTICES for v in range(10000)]
        with Client(f"127.0.0.1:{self.port}", token="main", timeout=120,
                    max_message_bytes=256 << 20) as c:
            tiled = c.matrix("spot", sources, targets)
        self.assertEqual(tiled.shape, (1024, 10000))
        self.assertEqual([tiled[v, v] for v in (0, 500, 1023)], [0, 0, 0])
        self.assertGreater(tiled[0, 1], 0)
        # The default client streams it in row blocks (MatrixRows): the same distances.
        with Client(f"127.0.0.1:{self.port}", token="main", timeout=120) as c:
            streamed = c.matrix("spot", sources, targets)
        self.assertTrue((streamed == tiled).all())

    def test_5_a_long_name_comes_back_cut(self):
        name = "m" * 10000
        with self.assertRaises(grpc.RpcError) as e:
            self.stub.GetMesh(pb.GetMeshRequest(name=name), timeout=10)
        self.assertEqual(e.exception.code(), grpc.StatusCode.NOT_FOUND, e.exception.details())
        self.assertLessEqual(len(e.exception.details()), 1100)
        self.assertIn("m" * 80, e.exception.details())
        self.assertNotIn("m" * 81, e.exception.details())


class MemoryLimitTest(unittest.TestCase):
    LIMIT = 300 << 20

    def test_a_flood_of_large_answers_stays_within_the_limit(self):
        work = tempfile.mkdtemp()
        daemon, ports = start_daemon(
            BIN, work, ["--graph-dir", f"{work}/graphs", "--log-level", "warning",
                        "--memory-limit", str(self.LIMIT)])
        try:
            with grpc.insecure_channel(f"127.0.0.1:{ports['grpc']}") as channel:
                stub = rpc.GeodesicStub(channel)
                wait_for_spot(stub)
                stub.Distance(pb.DistanceRequest(mesh="spot", pairs=[pb.PointPair(
                    **{"from": vertex(0), "to": vertex(1)})]), timeout=30)
                # What the daemon holds beside what the limit counts: binary,
                # gRPC, thread stacks, spot.
                baseline = rss_bytes(daemon.pid)
            # About 37 MB per answer, well under the message cap.
            targets = [vertex(v % SPOT_VERTICES) for v in range(8000)]

            def big_matrix(stub, seed):
                resp = stub.Matrix(pb.MatrixRequest(
                    mesh="spot", sources=[vertex((seed + k) % SPOT_VERTICES) for k in range(500)],
                    targets=targets), timeout=60)
                assert len(resp.distances) == 500 * 8000

            stop = threading.Event()
            crowd = Crowd(ports["grpc"], 24, [big_matrix], stop)
            crowd.run()
            peak = 0
            end = time.time() + min(SECONDS, 10)
            while time.time() < end:
                peak = max(peak, rss_bytes(daemon.pid))
                time.sleep(0.05)
            stop.set()
            crowd.join()
            peak = max(peak, rss_bytes(daemon.pid, "VmHWM"))
            print(f"idle RSS {baseline >> 20} MiB, peak {peak >> 20} MiB, limit "
                  f"{self.LIMIT >> 20} MiB, answers {crowd.counts}", file=sys.stderr)
            self.assertGreater(crowd.counts.get("OK", 0), 0, (crowd.counts, crowd.errors[:3]))
            self.assertEqual([e for e in crowd.errors if e[0] != "RESOURCE_EXHAUSTED"], [])
            self.assertLessEqual(peak, self.LIMIT + baseline,
                                 f"peak RSS {peak >> 20} MiB over the limit {self.LIMIT >> 20} "
                                 f"MiB + idle {baseline >> 20} MiB")
        finally:
            daemon_ports.stop(daemon)
            shutil.rmtree(work)


if __name__ == "__main__":
    unittest.main(argv=sys.argv[:1], verbosity=2)
