#!/usr/bin/python3
"""Fairness over HTTP: careless or hostile clients beside a well-behaved one.

- Token-less keep-alive connections, more than the connection cap, each
  refreshed: every 401 closes its connection, so the authenticated client is
  still answered.
- SIGTERM while HTTP requests wait on a graph build: the build is cancelled,
  the waiting requests are answered, and the daemon exits within
  --drain-seconds and a small margin.
- Meshes registered past --memory-limit are refused at registration, naming
  the limit, and queries keep answering; a body that cannot fit the limit is
  refused before it is read, an answer (a matrix as JSON) before it is made.
- A mesh scaled by 1e50 is refused at registration, naming the usable range.

Needs the shared meshes (../shared/meshes beside the source tree): without
them it fails.

Usage: fairness_http_test.py BUILD_BIN_DIR SOURCE_DIR
"""
import json
import os
import shutil
import socket
import sys
import tempfile
import threading
import time
import unittest

BIN, SRC = sys.argv[1], sys.argv[2]
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import daemon_ports  # noqa: E402
from daemon_ports import start_daemon  # noqa: E402
from geodesicd_runner import read_obj  # noqa: E402
from raw_http import read_response  # noqa: E402

SHARED = os.environ.get("GEODESIC_SHARED_DIR", os.path.join(SRC, "..", "shared"))
MESHES = os.path.join(SHARED, "meshes")
TOKEN = "fairness-test-token"
MAX_CONNECTIONS = 16
MEMORY_LIMIT = 48 << 20
DRAIN_SECONDS = 3
MIB = 1 << 20


def request(port, method, path, body=None, token=TOKEN, timeout=10.0):
    """One request on its own connection: (status, parsed JSON or raw body)."""
    payload = b"" if body is None else json.dumps(body).encode()
    lines = [f"{method} {path} HTTP/1.1", "Host: 127.0.0.1", "Connection: close"]
    if token:
        lines.append(f"Authorization: Bearer {token}")
    if body is not None:
        lines += ["Content-Type: application/json", f"Content-Length: {len(payload)}"]
    with socket.create_connection(("127.0.0.1", port), timeout=timeout) as s:
        s.sendall(("\r\n".join(lines) + "\r\n\r\n").encode() + payload)
        response = read_response(s, timeout)
    if response is None:
        return None, None
    status, _, raw = response
    try:
        return status, json.loads(raw)
    except ValueError:
        return status, raw


def error_message(answer):
    return answer.get("error", {}).get("message", "") if isinstance(answer, dict) else str(answer)


class GuardedDaemonTest(unittest.TestCase):
    """One daemon with a token, a small connection cap and a memory limit."""

    @classmethod
    def setUpClass(cls):
        if not os.path.exists(os.path.join(MESHES, "MANIFEST.md")):
            raise RuntimeError(f"the shared meshes are missing: {MESHES}")
        cls.work = tempfile.mkdtemp()
        with open(f"{cls.work}/token", "w") as f:
            f.write(TOKEN + "\n")
        cls.daemon, ports = start_daemon(
            BIN, cls.work,
            ["--graph-dir", f"{cls.work}/graphs", "--auth-token-file", f"{cls.work}/token",
             "--mesh-root", MESHES, "--memory-limit", str(MEMORY_LIMIT),
             "--http-max-connections", str(MAX_CONNECTIONS),
             "--http-max-connections-per-ip", str(MAX_CONNECTIONS), "--log-level", "warning"],
            http=True)
        cls.port = ports["http"]
        # The sample's graph, before anything competes for memory.
        status, answer = request(cls.port, "POST", "/v1/meshes/spot/distance",
                                 {"pairs": [["v:0", "v:100"]]}, timeout=60)
        assert status == 200, (status, answer)

    @classmethod
    def tearDownClass(cls):
        daemon_ports.stop(cls.daemon)
        shutil.rmtree(cls.work)

    def light_query(self):
        try:
            status, _ = request(self.port, "POST", "/v1/meshes/spot/distance",
                                {"pairs": [["v:0", "v:100"]]}, timeout=5)
        except (OSError, TimeoutError):
            return None
        return status

    def test_a_tokenless_keep_alive_flood_leaves_the_authenticated_client_answered(self):
        stop = threading.Event()

        def flood():
            # Keeps a keep-alive connection asking without a token; a
            # closed one is opened again after a short pause.
            while not stop.is_set():
                try:
                    with socket.create_connection(("127.0.0.1", self.port), timeout=2) as s:
                        while not stop.is_set():
                            s.sendall(b"GET /v1/meshes HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
                            if read_response(s, 2) is None:
                                break
                            stop.wait(0.3)
                except (OSError, TimeoutError):
                    pass
                stop.wait(0.3)

        flooders = [threading.Thread(target=flood, daemon=True)
                    for _ in range(3 * MAX_CONNECTIONS)]
        for t in flooders:
            t.start()
        try:
            time.sleep(1.0)
            answered = 0
            for _ in range(20):
                answered += self.light_query() == 200
                time.sleep(0.1)
        finally:
            stop.set()
            for t in flooders:
                t.join(timeout=5)
        self.assertGreaterEqual(answered, 18, f"{answered} of 20 answered beside the flood")

    def test_b_a_401_closes_its_connection(self):
        with socket.create_connection(("127.0.0.1", self.port), timeout=5) as s:
            s.sendall(b"GET /v1/meshes HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            status, headers, _ = read_response(s, 5)
            self.assertEqual(status, 401)
            self.assertEqual(headers.get("connection", "").lower(), "close")
            s.settimeout(5)
            self.assertEqual(s.recv(1), b"", "the connection stayed open after the 401")

    def test_c_registrations_past_the_memory_limit_are_refused_and_queries_answer(self):
        refused, registered = None, []
        self.addCleanup(lambda: [request(self.port, "DELETE", f"/v1/meshes/{name}")
                                 for name in registered])
        # Each registration is a copy of its own (about 13 MiB of arrays).
        for i in range(8):
            status, answer = request(self.port, "POST", "/v1/meshes",
                                     {"name": f"copy{i}", "path": "armadillo.obj"}, timeout=60)
            if status != 200:
                refused = (i, status, error_message(answer))
                break
            registered.append(f"copy{i}")
        self.assertIsNotNone(refused, "8 copies of a 50K-vertex mesh registered under "
                             f"--memory-limit {MEMORY_LIMIT}")
        self.assertEqual(refused[1], 429, refused)
        self.assertIn("--memory-limit", refused[2])
        self.assertGreater(refused[0], 0, refused)
        answered = sum(self.light_query() == 200 for _ in range(5))
        self.assertEqual(answered, 5, "queries refused after the registrations")

    def test_d_a_body_that_cannot_fit_the_memory_limit_is_refused_before_it_is_read(self):
        with socket.create_connection(("127.0.0.1", self.port), timeout=5) as s:
            s.sendall(("POST /v1/meshes/spot/distance HTTP/1.1\r\nHost: 127.0.0.1\r\n"
                       f"Authorization: Bearer {TOKEN}\r\nContent-Type: application/json\r\n"
                       f"Content-Length: {15 * MIB}\r\n\r\n").encode())
            response = read_response(s, 5)
        self.assertIsNotNone(response, "closed without an answer")
        self.assertIn(response[0], (413, 503), response)
        self.assertIn(b"--memory-limit", response[2])

    def test_f_answers_that_cannot_fit_the_memory_limit_are_refused_before_they_are_made(self):
        # 400 x 2930 distances: their JSON would take about 64 bytes each (value, tree and
        # text), past the limit, though the RPC's own answer (8 bytes each) fits.
        sources = [f"v:{v}" for v in range(400)]
        targets = [f"v:{v}" for v in range(2930)]
        status, answer = request(self.port, "POST", "/v1/meshes/spot/matrix",
                                 {"sources": sources, "targets": targets}, timeout=60)
        # 429 (RESOURCE_EXHAUSTED): it can never fit; 503 if it could later.
        self.assertIn(status, (429, 503), (status, str(answer)[:300]))
        self.assertIn("--memory-limit", error_message(answer))
        self.assertIn("a matrix of 400 x 2930 as JSON", error_message(answer))
        # A small one still fits, and queries keep answering.
        status, answer = request(self.port, "POST", "/v1/meshes/spot/matrix",
                                 {"sources": sources[:4], "targets": targets[:100]}, timeout=60)
        self.assertEqual(status, 200, answer)
        self.assertEqual(len(answer["distances"]), 4)
        self.assertEqual(self.light_query(), 200)

    def test_e_a_mesh_scaled_past_the_usable_range_is_refused(self):
        vertices, faces = read_obj(os.path.join(SRC, "data", "spot.obj"))
        for factor, measure in ((1e50, "diagonal"), (1e-50, "too short")):
            status, answer = request(
                self.port, "POST", "/v1/meshes",
                {"name": "scaled", "vertices": (vertices * factor).tolist(),
                 "faces": faces.tolist()}, timeout=30)
            self.assertEqual(status, 400, (factor, answer))
            message = error_message(answer)
            self.assertIn(measure, message)
            self.assertIn("usable range", message)
            self.assertIn("1e-30", message)
            self.assertIn("1e+30", message)
        status, answer = request(
            self.port, "POST", "/v1/meshes",
            {"name": "scaled", "vertices": (vertices * 1e6).tolist(), "faces": faces.tolist()},
            timeout=30)
        self.assertEqual(status, 200, answer)


class ShutdownTest(unittest.TestCase):
    def test_sigterm_while_requests_wait_on_a_build_exits_within_the_drain(self):
        if not os.path.exists(os.path.join(MESHES, "armadillo.obj")):
            raise RuntimeError(f"the shared meshes are missing: {MESHES}")
        work = tempfile.mkdtemp()
        try:
            daemon, ports = start_daemon(
                BIN, work,
                ["--graph-dir", f"{work}/graphs", "--mesh-root", MESHES, "--no-sample",
                 "--drain-seconds", str(DRAIN_SECONDS), "--log-level", "warning"], http=True)
            port = ports["http"]
            status, answer = request(port, "POST", "/v1/meshes",
                                     {"name": "big", "path": "armadillo.obj"}, token=None,
                                     timeout=60)
            self.assertEqual(status, 200, answer)
            answers = []

            def wait_on_build(i):
                try:
                    answers.append(request(port, "POST", "/v1/meshes/big/distance",
                                           {"pairs": [["v:0", f"v:{1000 + i}"]]}, token=None,
                                           timeout=DRAIN_SECONDS + 20))
                except (OSError, TimeoutError) as e:
                    answers.append((None, repr(e)))

            waiters = [threading.Thread(target=wait_on_build, args=(i,)) for i in range(3)]
            for t in waiters:
                t.start()
            time.sleep(1.5)
            self.assertIsNone(daemon.poll())
            self.assertEqual(answers, [], "the build ended before the signal: use a larger mesh")
            start = time.time()
            code = daemon_ports.stop(daemon, timeout=DRAIN_SECONDS + 12)
            seconds = time.time() - start
            for t in waiters:
                t.join(timeout=15)
            self.assertIsNotNone(code, "killed: it did not exit")
            self.assertLess(seconds, DRAIN_SECONDS + 3,
                            f"exited {seconds:.1f} s after SIGTERM (--drain-seconds "
                            f"{DRAIN_SECONDS})")
            self.assertEqual(len(answers), 3, answers)
            for status, answer in answers:
                self.assertIsNotNone(status, f"closed without an answer: {answer}")
        finally:
            shutil.rmtree(work)


if __name__ == "__main__":
    unittest.main(argv=[sys.argv[0], "-v"])
