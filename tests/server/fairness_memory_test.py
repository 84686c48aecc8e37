#!/usr/bin/python3
"""Resident memory under --memory-limit (#55, item 4): the daemon's RSS stays within the limit
plus its fixed overhead while hostile clients ask for more, and a well-behaved client beside
them is answered.

The fixed overhead is measured as docs/limits.md's --memory-limit paragraph defines it: the
daemon's idle resident memory (the sample mesh's graph ready, one query answered) less what
its memory gauges count (geodesicd_mesh_resident_bytes, geodesicd_graph_resident_bytes,
geodesicd_graph_mapped_bytes, geodesicd_query_scratch_bytes). Each case runs on a daemon of
its own, whose VmRSS a thread samples every 20 ms from /proc; the peak (the largest sample, or
VmHWM if larger) must stay within the limit + the overhead + SLACK. The cases:

1. --memory-limit 256M: eight gRPC UploadMesh streams each declaring 240 MiB, left open after
   their first message of 1 MiB: each holds what it sent, not what it declared (#67: three
   such trickling uploads held 696 MB of a 700M limit and refused everyone else's), so none
   is refused and another client's upload is registered beside them.
2. --memory-limit 256M: armadillo.obj (50K vertices) registered under 60 names, one after the
   other: past the limit the registrations are refused naming it, and queries keep being
   answered afterwards.
3. --memory-limit 512M: eight concurrent HTTP GET .../geometry of armadillo_loop2.ply (800K
   vertices, about 74 MiB of JSON each), each retried on 503 for a while: some answered whole,
   the others 503 (or 413); none pushes RSS past the bound.
4. --memory-limit 512M: sixteen concurrent HTTP POST .../distance whose JSON bodies are lists
   of pairs of one-digit "v:ID" strings, the body that takes the most memory per byte: eight
   of 16 MiB (the body cap), which can never fit 512M at the reservation's factor (64 times
   the length): 413 before the body is sent; and eight of 7 MiB, which fit one at a time, so
   that bodies are really read and parsed while the others wait (503, retried). (Reserved at
   32 times their length, two of these fitted at once, each taking about 51 times its length:
   RSS reached 736 MiB, 170 MiB past the bound; at 64 times, without handing freed pages back
   as a reservation ends, a body was made beside the last one's pages: up to 584 MiB.)
5. --memory-limit 256M: armadillo_loop2.ply (800K vertices) registered: refused from its
   counts before it is built, naming the limit and the estimate (built first, it took RSS to
   415 MiB before its refusal).
6. --memory-limit 512M: armadillo_loop2.ply registered, then 100 regions of one face each: all
   registered, each counted in geodesicd_mesh_resident_bytes and small (#67: 9.6 MB each in
   parent-sized tables, uncounted).

In every case a light client sends 20 one-pair Distance calls on the bundled spot mesh beside
the load: at least 18 must be answered (in case 2, also after the registrations).

Needs the shared meshes (../shared/meshes beside the source tree, or GEODESIC_SHARED_DIR):
without them it fails. Every daemon listens on 127.0.0.1 port 0, every call has a deadline.

Usage: fairness_memory_test.py BUILD_BIN_DIR SOURCE_DIR
"""
import contextlib
import http.client
import math
import os
import shutil
import socket
import sys
import tempfile
import threading
import time

BIN, SRC = sys.argv[1], sys.argv[2]
sys.path.insert(0, os.path.join(SRC, "client", "python"))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import grpc  # noqa: E402
from geodesic_client import Client  # noqa: E402
from geodesic_client._stubs import pb, rpc  # noqa: E402
import daemon_ports  # noqa: E402
from checklist import Checklist  # noqa: E402
from daemon_ports import metrics, rss_bytes, start_daemon  # noqa: E402
from fairness_clients import light_queries, wait_ready  # noqa: E402
from raw_http import read_response  # noqa: E402

SHARED = os.environ.get("GEODESIC_SHARED_DIR", os.path.join(SRC, "..", "shared"))
MESHES = os.path.join(SHARED, "meshes")
MIB = 1 << 20
LARGE_MESH, LARGE_VERTICES = "armadillo_loop2.ply", 799810
# What the peak may pass the limit + the idle overhead by: the stacks and malloc arenas of
# the threads that calls running at once under load start (idle, the daemon has fewer), and
# what one call holds before the gauges count it (a registration's parse: about 8 MiB here).
# Small beside the limits.
SLACK = 32 * MIB
# The gauges of what --memory-limit counts (README, --memory-limit).
COUNTED = ("mesh_resident_bytes", "graph_resident_bytes", "graph_mapped_bytes",
           "query_scratch_bytes")
LIGHT_QUERIES = 20
SAMPLE_SECONDS = 0.02

check = Checklist()
work = tempfile.mkdtemp(prefix="fairness-memory-")


class Guarded:
    """A daemon under --memory-limit `limit`: its fixed overhead measured once idle, then its
    VmRSS sampled until stop()."""

    def __init__(self, name, limit, http=False):
        self.name, self.limit = name, limit
        self.log = os.path.join(work, f"{name}.log")
        with open(self.log, "w") as log:
            self.process, self.ports = start_daemon(
                BIN, os.path.join(work, name),
                ["--graph-dir", os.path.join(work, name, "graphs"), "--mesh-root", MESHES,
                 "--memory-limit", str(limit), "--log-level", "warning"],
                stderr=log, metrics=True, http=http)
        self.address = f"127.0.0.1:{self.ports['grpc']}"
        self.channel = grpc.insecure_channel(self.address)
        self.stub = rpc.GeodesicStub(self.channel)
        self.samples, self.hwm, self.load_from = [], 0, 0
        self.idle = self.counted = self.overhead = math.nan
        self._stop = threading.Event()
        self._sampler = threading.Thread(target=self._sample, daemon=True)

    def measure_overhead(self):
        """Idle RSS less the counted gauges, once spot's graph is ready and a query answered
        (its first allocations belong to the idle state). False if spot never got ready."""
        if not wait_ready(self.stub, "spot") or len(light_queries(self.stub, 1, 0)[0]) != 1:
            return False
        time.sleep(0.2)
        values = metrics(self.ports["metrics"])
        self.counted = sum(values[f"geodesicd_{g}"] for g in COUNTED)
        self.idle = rss_bytes(self.process.pid)
        self.overhead = self.idle - self.counted
        self._sampler.start()
        return True

    def load_starts(self):
        """Marks where the hostile load begins, for the report (setup came before)."""
        self.load_from = len(self.samples)

    def _sample(self):
        while not self._stop.is_set():
            try:
                self.samples.append(rss_bytes(self.process.pid))
            except (OSError, AttributeError):  # exited: no status, or no VmRSS line
                return
            self._stop.wait(SAMPLE_SECONDS)

    def stop(self):
        self._stop.set()
        if self._sampler.is_alive():
            self._sampler.join(timeout=5)
        try:
            self.hwm = rss_bytes(self.process.pid, "VmHWM")
        except (OSError, AttributeError):
            pass
        self.channel.close()
        daemon_ports.stop(self.process)

    def check_peak(self, case):
        """The overhead real, the samples real, and the peak within the bound."""
        check(f"{case}: the overhead is measured (finite, positive, below the limit)",
              math.isfinite(self.overhead) and 0 < self.overhead < self.limit,
              f"idle {self.idle}, counted {self.counted}")
        check(f"{case}: resident memory was sampled (at least 10 samples, all positive)",
              len(self.samples) >= 10 and min(self.samples) > 0 and self.hwm > 0,
              f"{len(self.samples)} samples, VmHWM {self.hwm}")
        if not self.samples or not math.isfinite(self.overhead):
            return
        peak = max(max(self.samples), self.hwm)
        load = max(self.samples[self.load_from:], default=0)
        bound = self.limit + self.overhead + SLACK
        print(f"{case}: --memory-limit {self.limit / MIB:.0f} MiB; idle RSS "
              f"{self.idle / MIB:.1f} MiB, counted {self.counted / MIB:.1f} MiB, overhead "
              f"{self.overhead / MIB:.1f} MiB; peak RSS {peak / MIB:.1f} MiB (largest of "
              f"{len(self.samples)} samples {max(self.samples) / MIB:.1f}, during the load "
              f"{load / MIB:.1f}; VmHWM {self.hwm / MIB:.1f}); bound {bound / MIB:.1f} MiB "
              f"(limit + overhead + {SLACK / MIB:.0f} MiB slack)", flush=True)
        check(f"{case}: peak RSS within --memory-limit + the overhead + {SLACK // MIB} MiB",
              peak <= bound, f"peak {peak / MIB:.1f} MiB > bound {bound / MIB:.1f} MiB")


class Beside:
    """The light client's queries on a thread of their own, beside a load."""

    def __init__(self, stub):
        self.result = ([], ["never ran"])
        self.thread = threading.Thread(target=self.run, args=(stub,))
        self.thread.start()

    def run(self, stub):
        self.result = light_queries(stub, LIGHT_QUERIES, pause=0.1)

    def check(self, case, seconds=60):
        self.thread.join(timeout=seconds)
        latencies, errors = self.result
        check(f"{case}: at least 18 of {LIGHT_QUERIES} light queries answered beside it",
              len(latencies) >= 18, f"{len(latencies)} answered; errors {errors[:3]}")


def all_at_once_beside(d, case, n, attempt):
    """attempt(0) .. attempt(n - 1) on threads of their own, all at once, with the light client
    beside them from half a second in: their results, once its answers are checked."""
    results = [None] * n

    def run(k):
        results[k] = attempt(k)

    threads = [threading.Thread(target=run, args=(k,)) for k in range(n)]
    for t in threads:
        t.start()
    time.sleep(0.5)
    beside = Beside(d.stub)
    for t in threads:
        t.join(timeout=90)
    beside.check(case)
    return results


@contextlib.contextmanager
def guarded(case, name, limit, http=False):
    """A Guarded daemon for `case`, once its overhead is measured (None if spot never got
    ready); stopped afterwards, and its peak checked if it was measured."""
    d = Guarded(name, limit, http)
    measured = False
    try:
        measured = check(f"{case}: spot ready, overhead measured", d.measure_overhead())
        yield d if measured else None
    finally:
        d.stop()
    if measured:
        d.check_peak(case)


def names_the_limit(code, details):
    return code in (grpc.StatusCode.RESOURCE_EXHAUSTED, grpc.StatusCode.UNAVAILABLE) and \
        "--memory-limit" in (details or "")


def case_uploads(limit):
    case = "(1) uploads left open"
    declared, streams = 240 * MIB, 8
    release = threading.Event()
    channels = []
    with guarded(case, "uploads", limit) as d:
        if d is None:
            return
        try:
            first = b"v 0 0 0\n" * (MIB // 8)  # a first message of 1 MiB

            def one_then_nothing(i):
                yield pb.UploadMeshRequest(name=f"upload{i}", format="obj", total_bytes=declared,
                                           sha256="0" * 64, data=first)
                release.wait(60)

            meshes = metrics(d.ports["metrics"])["geodesicd_mesh_resident_bytes"]
            fits = int((limit - meshes) // declared)
            channels = [grpc.insecure_channel(d.address) for _ in range(streams)]
            d.load_starts()
            calls = [rpc.GeodesicStub(ch).UploadMesh.future(one_then_nothing(i), timeout=60)
                     for i, ch in enumerate(channels)]
            time.sleep(1.0)  # every first message in
            beside = Beside(d.stub)
            refused = [c for c in calls if c.done()]
            details = [(c.code().name, c.details()) for c in refused]
            print(f"{case}: {fits} of {streams} would fit if their declared bytes were held; "
                  f"ended {details[:2]}", flush=True)
            check(f"{case}: none is refused: each holds what it sent, not what it declared",
                  not refused, details[:2])
            with Client(d.address, timeout=60) as client:
                registered = client.upload_mesh("beside", os.path.join(SRC, "data", "spot.obj"))
            check(f"{case}: another client's upload is registered beside them",
                  registered.diagnostics.vertices == 2930, registered)
            beside.check(case)
            check(f"{case}: every upload is still held open",
                  sum(not c.done() for c in calls) == streams, f"{streams} open")
        finally:
            release.set()
            for ch in channels:
                ch.close()


def case_registrations(limit):
    case = "(2) 60 registrations of one mesh"
    with guarded(case, "registrations", limit) as d:
        if d is None:
            return
        d.load_starts()
        beside = Beside(d.stub)
        registered, refusals, others = 0, [], []
        for i in range(60):
            try:
                d.stub.RegisterMesh(pb.RegisterMeshRequest(name=f"copy{i}", path="armadillo.obj"),
                                    timeout=30)
                registered += 1
            except grpc.RpcError as e:
                (refusals if names_the_limit(e.code(), e.details()) else others).append(
                    f"{e.code().name}: {e.details()}")
        print(f"{case}: {registered} registered, {len(refusals)} refused", flush=True)
        check(f"{case}: some registered, the rest refused naming --memory-limit",
              0 < registered < 60 and registered + len(refusals) == 60 and not others,
              f"{registered} registered; {others[:2]}")
        beside.check(case)
        latencies, errors = light_queries(d.stub, LIGHT_QUERIES, pause=0.1)
        check(f"{case}: queries keep being answered afterwards (at least 18 of "
              f"{LIGHT_QUERIES})", len(latencies) >= 18,
              f"{len(latencies)} answered; {errors[:3]}")


def case_large_mesh(limit):
    case = "(5) a mesh larger than the limit"
    with guarded(case, "large", limit) as d:
        if d is None:
            return
        d.load_starts()
        beside = Beside(d.stub)
        try:
            d.stub.RegisterMesh(pb.RegisterMeshRequest(name="large", path=LARGE_MESH), timeout=60)
            code, details = grpc.StatusCode.OK, ""
        except grpc.RpcError as e:
            code, details = e.code(), e.details() or ""
        # Refused from its counts, before the build that took several times the file's bytes.
        check(f"{case}: refused before it is built, naming --memory-limit and the estimate",
              names_the_limit(code, details) and
              f"estimated from its {LARGE_VERTICES} vertices" in details, (code.name, details))
        beside.check(case)


def retried(attempt, seconds):
    """attempt() -> (status, ...) repeated while it answers 503, for at most `seconds`."""
    deadline = time.time() + seconds
    result = attempt()
    while result[0] == 503 and time.time() < deadline:
        time.sleep(0.2)
        result = attempt()
    return result


def get_geometry(port, name, timeout=60):
    """(status, bytes of the body read, its first bytes): the body is read and dropped."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=timeout)
    try:
        conn.request("GET", f"/v1/meshes/{name}/geometry")
        response = conn.getresponse()
        head, size = b"", 0
        while chunk := response.read(MIB):
            head = head or chunk[:300]
            size += len(chunk)
        return response.status, size, head
    except (OSError, http.client.HTTPException) as e:
        return None, 0, repr(e).encode()
    finally:
        conn.close()


def case_geometry(limit):
    case = "(3) concurrent geometry of the 800K mesh"
    with guarded(case, "geometry", limit, http=True) as d:
        if d is None:
            return
        mesh = d.stub.RegisterMesh(pb.RegisterMeshRequest(name="big", path=LARGE_MESH),
                                   timeout=120)
        vertices = mesh.diagnostics.vertices
        d.load_starts()
        results = all_at_once_beside(
            d, case, 8, lambda k: retried(lambda: get_geometry(d.ports["http"], "big"), 20))
        statuses = [r[0] if r else None for r in results]
        whole = [r for r in results if r and r[0] == 200 and r[1] > 40 * MIB]
        print(f"{case}: {vertices} vertices; statuses {statuses}; bodies "
              f"{[round(r[1] / MIB, 1) for r in results if r]} MiB", flush=True)
        check(f"{case}: some geometry answered whole (over 40 MiB of JSON)", whole,
              [(r[0], r[1], r[2][:200]) for r in results if r])
        check(f"{case}: every request answered 200, or refused 503/413 naming --memory-limit",
              all(r and (r[0] == 200 or (r[0] in (503, 413) and b"--memory-limit" in r[2]))
                  for r in results),
              [(r[0], r[2][:200]) for r in results if r and r[0] != 200])


def case_regions(limit):
    case = "(6) 100 regions of the 800K mesh"
    with guarded(case, "regions", limit) as d:
        if d is None:
            return
        d.stub.RegisterMesh(pb.RegisterMeshRequest(name="big", path=LARGE_MESH), timeout=120)
        before = metrics(d.ports["metrics"])["geodesicd_mesh_resident_bytes"]
        d.load_starts()
        beside = Beside(d.stub)
        registered, errors = 0, []
        for k in range(100):
            try:
                d.stub.RegisterRegion(pb.RegisterRegionRequest(
                    name=f"face{k}", parent="big", face_ids=[k * 15000]), timeout=30)
                registered += 1
            except grpc.RpcError as e:
                errors.append(f"{e.code().name}: {e.details()}")
        added = metrics(d.ports["metrics"])["geodesicd_mesh_resident_bytes"] - before
        print(f"{case}: {registered} registered, adding {added / MIB:.2f} MiB to the meshes' "
              f"gauge; errors {errors[:2]}", flush=True)
        # A one-face region is three vertices and their maps: counted, and small beside its
        # parent (they once took 9.6 MB each in parent-sized tables, uncounted).
        check(f"{case}: every region registered, counted and small",
              registered == 100 and 0 < added < 100 * 64 * 1024, f"{added} bytes; {errors[:2]}")
        beside.check(case)


def pairs_body(size):
    """A distance request's JSON of exactly `size` bytes: pairs of one-digit vertex ids (the
    shortest tokens, each pair parsed and copied into several structures), spaces to pad."""
    pair = b'["v:1","v:2"]'
    pairs = b",".join([pair] * ((size - 16) // (len(pair) + 1)))
    body = b'{"pairs":[' + pairs + b"]"
    return body + b" " * (size - len(body) - 1) + b"}"


def post_body(port, path, body, timeout=30):
    """A POST announcing its body with Expect: 100-continue (as curl does past 1 MiB): the
    body is sent only once the gateway says it reads it. (status, body of the answer, whether
    the body was sent); (None, why, sent) if the connection closed without an answer."""
    head = (f"POST {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n"
            f"Content-Type: application/json\r\nContent-Length: {len(body)}\r\n"
            "Expect: 100-continue\r\n\r\n").encode()
    sent = False
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=timeout) as s:
            s.sendall(head)
            response = read_response(s, timeout)
            if response and response[0] == 100:
                s.sendall(body)
                sent = True
                response = read_response(s, timeout)
    except (OSError, TimeoutError) as e:
        return None, repr(e).encode(), sent
    if response is None:
        return None, b"closed without an answer", sent
    return response[0], response[2], sent


def case_bodies(limit):
    case = "(4) concurrent 16 and 7 MiB bodies"
    with guarded(case, "bodies", limit, http=True) as d:
        if d is None:
            return
        never = pairs_body(16 * MIB)  # the gateway's body cap, 1 GiB reserved
        fits = pairs_body(7 * MIB)  # 448 MiB reserved: one at a time
        path = "/v1/meshes/spot/distance"
        d.load_starts()
        results = all_at_once_beside(
            d, case, 16,
            lambda k: retried(lambda: post_body(d.ports["http"], path, never if k % 2 else fits),
                              30))
        summary = [(r[0], r[2]) if r else None for r in results]
        print(f"{case}: (status, body sent) of the 16 MiB bodies {summary[1::2]}, of the "
              f"7 MiB ones {summary[::2]}", flush=True)
        never_answers = [r for r in results[1::2] if r]
        check(f"{case}: every 16 MiB body refused 413 naming --memory-limit, before it is sent",
              len(never_answers) == 8 and all(
                  r[0] == 413 and b"--memory-limit" in r[1] and not r[2] for r in never_answers),
              [(r[0], r[1][:200], r[2]) for r in never_answers])
        read = [r for r in results[::2] if r and r[2]]
        check(f"{case}: 7 MiB bodies were read and answered (the limit admitted them)",
              read and all(r[0] is not None and r[0] < 500 for r in read),
              [(r[0], r[1][:200], r[2]) if r else None for r in results[::2]])
        check(f"{case}: the others refused 503 naming --memory-limit",
              all(r and (r[2] or (r[0] == 503 and b"--memory-limit" in r[1]))
                  for r in results[::2]),
              [(r[0], r[1][:200]) for r in results[::2] if r and not r[2]])


def main():
    started = time.monotonic()
    if not check("the shared meshes are there", all(
            os.path.exists(os.path.join(MESHES, m)) for m in
            ("MANIFEST.md", "armadillo.obj", "armadillo_loop2.ply")), MESHES):
        return
    for run, limit in ((case_uploads, 256 * MIB), (case_registrations, 256 * MIB),
                       (case_geometry, 512 * MIB), (case_bodies, 512 * MIB),
                       (case_large_mesh, 256 * MIB), (case_regions, 512 * MIB)):
        case_started = time.monotonic()
        run(limit)
        print(f"{run.__name__}: {time.monotonic() - case_started:.1f} s", flush=True)
    print(f"{time.monotonic() - started:.1f} s", flush=True)


if __name__ == "__main__":
    try:
        main()
    except RuntimeError as e:  # a daemon that would not start
        check("daemon started", False, str(e)[-2000:])
    finally:
        shutil.rmtree(work, ignore_errors=True)
    check.finish()
