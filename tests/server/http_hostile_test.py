#!/usr/bin/python3
"""The HTTP gateway against clients that misbehave, on 127.0.0.1 sockets.

A body nobody is allowed to send is never read: without the token the answer
is 401 right after the headers, whatever the body (chunked, huge, not JSON);
bodies, chunked ones included, are capped while they are read; headers and
bodies that trickle are cut at their deadlines; slow clients do not hold the
threads that answer others; connections per client address are bounded.

Usage: http_hostile_test.py BUILD_BIN_DIR SOURCE_DIR
"""
import os
import select
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
from raw_http import read_response  # noqa: E402

TOKEN = "hostile-test-token"
HEADER_TIMEOUT = 2.0
BODY_TIMEOUT = 2.0
PER_IP = 48
MIB = 1 << 20


def vm_hwm_bytes(pid):
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
    raise RuntimeError("no VmHWM")


def request(port, method, path, headers=(), body=b"", timeout=5.0):
    with socket.create_connection(("127.0.0.1", port), timeout=timeout) as s:
        lines = [f"{method} {path} HTTP/1.1", "Host: 127.0.0.1", "Connection: close", *headers]
        if body:
            lines.append(f"Content-Length: {len(body)}")
        s.sendall(("\r\n".join(lines) + "\r\n\r\n").encode() + body)
        return read_response(s, timeout)


def is_closed(sock):
    """Whether the peer closed (or reset) the connection; never blocks."""
    readable, _, _ = select.select([sock], [], [], 0)
    if not readable:
        return False
    try:
        sock.setblocking(False)
        return sock.recv(65536) == b""
    except BlockingIOError:
        return False
    except OSError:
        return True


class HostileClientTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.work = tempfile.mkdtemp()
        with open(f"{cls.work}/token", "w") as f:
            f.write(TOKEN + "\n")
        limits = ["--http-listen", "127.0.0.1:0", "--no-sample",
                  "--http-header-timeout", str(HEADER_TIMEOUT),
                  "--http-body-timeout", str(BODY_TIMEOUT),
                  "--http-max-connections-per-ip", str(PER_IP), "--log-level", "warning"]
        os.mkdir(f"{cls.work}/a")
        os.mkdir(f"{cls.work}/b")
        cls.guarded, ports = start_daemon(
            BIN, f"{cls.work}/a",
            ["--graph-dir", f"{cls.work}/a/graphs", "--auth-token-file", f"{cls.work}/token",
             *limits])
        cls.guarded_port = ports["http"]
        cls.open, ports = start_daemon(BIN, f"{cls.work}/b",
                                       ["--graph-dir", f"{cls.work}/b/graphs", *limits])
        cls.open_port = ports["http"]

    @classmethod
    def tearDownClass(cls):
        for daemon in (cls.guarded, cls.open):
            daemon_ports.stop(daemon)
        shutil.rmtree(cls.work)

    def auth(self):
        return [f"Authorization: Bearer {TOKEN}"]

    def chunked_flood(self, daemon, port, headers):
        """Streams up to 64 MiB of chunks until the server answers; returns
        (response, seconds, VmHWM growth)."""
        before = vm_hwm_bytes(daemon.pid)
        start = time.time()
        chunk = os.urandom(1024) * 1024
        frame = f"{len(chunk):x}\r\n".encode() + chunk + b"\r\n"
        with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
            s.sendall(("POST /v1/meshes/spot/distance HTTP/1.1\r\nHost: 127.0.0.1\r\n"
                       "Content-Type: application/json\r\nTransfer-Encoding: chunked\r\n" +
                       "".join(h + "\r\n" for h in headers) + "\r\n").encode())
            sent = 0
            while sent < 64 * MIB and time.time() - start < 20:
                readable, writable, _ = select.select([s], [s], [], 1.0)
                if readable:
                    break
                if not writable:
                    continue
                try:
                    sent += s.send(frame[sent % len(frame):])
                except OSError:
                    break
            response = read_response(s, timeout=10)
        return response, time.time() - start, vm_hwm_bytes(daemon.pid) - before

    def test_chunked_flood_without_token_gets_401_before_the_body_is_read(self):
        response, seconds, growth = self.chunked_flood(self.guarded, self.guarded_port, [])
        self.assertIsNotNone(response, "closed without an answer")
        self.assertEqual(response[0], 401, response)
        self.assertEqual(response[1].get("www-authenticate"), "Bearer")
        self.assertLess(seconds, 5)
        self.assertLess(growth, 64 * MIB, f"VmHWM grew by {growth / MIB:.0f} MiB")

    def test_chunked_flood_is_cut_at_the_body_limit(self):
        response, seconds, growth = self.chunked_flood(self.open, self.open_port, [])
        self.assertIsNotNone(response, "closed without an answer")
        self.assertEqual(response[0], 413, response)
        self.assertIn(b"RESOURCE_EXHAUSTED", response[2])
        self.assertLess(seconds, 10)
        self.assertLess(growth, 64 * MIB, f"VmHWM grew by {growth / MIB:.0f} MiB")

    def test_unauthenticated_bad_body_gets_401_not_400(self):
        status, headers, body = request(self.guarded_port, "POST", "/v1/meshes/spot/distance",
                                        ["Content-Type: application/json"], b"{not json")
        self.assertEqual(status, 401, body)
        self.assertIn(b"UNAUTHENTICATED", body)
        status, _, body = request(self.guarded_port, "POST", "/v1/meshes/spot/distance",
                                  ["Content-Type: application/json", *self.auth()], b"{not json")
        self.assertEqual(status, 400, body)

    def test_duplicated_authorization_header_is_refused(self):
        good, bad = f"Authorization: Bearer {TOKEN}", "Authorization: Bearer wrong"
        status, _, body = request(self.guarded_port, "GET", "/v1/meshes", [good])
        self.assertEqual(status, 200, body)
        for pair in ([bad, good], [good, bad], [good, good]):
            status, _, body = request(self.guarded_port, "GET", "/v1/meshes", pair)
            self.assertEqual(status, 401, (pair, body))

    def slowloris(self, count):
        """`count` connections trickling header bytes; normal requests beside
        them answer within a second; each slow one is closed at the header
        deadline."""
        slow = []
        for _ in range(count):
            s = socket.create_connection(("127.0.0.1", self.guarded_port), timeout=5)
            s.sendall(b"G")
            slow.append(s)
        opened = time.time()
        closed_at = {}
        stop = threading.Event()
        header = b"ET /v1/meshes HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: " + b"a" * 1000

        def trickle():
            i = 0
            while not stop.is_set() and len(closed_at) < len(slow) and time.time() - opened < 15:
                for k, s in enumerate(slow):
                    if k in closed_at:
                        continue
                    if is_closed(s):
                        closed_at[k] = time.time()
                        continue
                    try:
                        s.setblocking(True)
                        s.settimeout(1)
                        s.send(header[i % len(header):i % len(header) + 1])
                    except OSError:
                        closed_at[k] = time.time()
                i += 1
                time.sleep(0.2)

        thread = threading.Thread(target=trickle)
        thread.start()
        try:
            time.sleep(0.5)
            for path, headers in [("/v1/meshes", self.auth()), ("/index.html", []),
                                  ("/v1/meshes", self.auth()), ("/viewer.js", [])]:
                start = time.time()
                status, _, body = request(self.guarded_port, "GET", path, headers, timeout=3)
                self.assertEqual(status, 200, (path, body[:200]))
                self.assertLess(time.time() - start, 1.0, f"{path} beside {count} slow clients")
            thread.join(timeout=HEADER_TIMEOUT + 8)
            self.assertEqual(len(closed_at), count, "slow clients still open")
            for k, t in closed_at.items():
                self.assertGreater(t - opened, HEADER_TIMEOUT * 0.5, "closed before the deadline")
                self.assertLess(t - opened, HEADER_TIMEOUT + 3, "not closed at the header deadline")
        finally:
            stop.set()
            thread.join()
            for s in slow:
                s.close()

    def test_slowloris_does_not_lock_out_the_gateway(self):
        self.slowloris(8)
        self.slowloris(40)

    def test_slow_body_is_cut_at_the_body_deadline(self):
        with socket.create_connection(("127.0.0.1", self.guarded_port), timeout=5) as s:
            s.sendall(("POST /v1/meshes/spot/distance HTTP/1.1\r\nHost: 127.0.0.1\r\n"
                       f"Authorization: Bearer {TOKEN}\r\nContent-Type: application/json\r\n"
                       "Content-Length: 1000\r\n\r\n{").encode())
            start = time.time()
            closed = None
            while time.time() - start < BODY_TIMEOUT + 5:
                if is_closed(s):
                    closed = time.time() - start
                    break
                try:
                    s.setblocking(True)
                    s.send(b" ")
                except OSError:
                    closed = time.time() - start
                    break
                time.sleep(0.2)
            self.assertIsNotNone(closed, "a body trickling past the body deadline was not cut")
            self.assertGreater(closed, BODY_TIMEOUT * 0.5)
            self.assertLess(closed, BODY_TIMEOUT + 3)

    def test_connections_per_address_are_bounded(self):
        held = [socket.create_connection(("127.0.0.1", self.open_port), timeout=5)
                for _ in range(PER_IP)]
        try:
            time.sleep(0.3)
            with socket.create_connection(("127.0.0.1", self.open_port), timeout=5) as extra:
                response = read_response(extra, timeout=5)
                if response is not None:  # answered 503, or just closed
                    self.assertEqual(response[0], 503, response)
        finally:
            for s in held:
                s.close()
        time.sleep(0.3)
        status, _, body = request(self.open_port, "GET", "/v1/meshes")
        self.assertEqual(status, 200, body)

    def test_wrong_method_gets_405_and_traversal_is_refused(self):
        status, headers, body = request(self.open_port, "PUT", "/v1/meshes/spot/distance")
        self.assertEqual(status, 405, body)
        self.assertEqual(headers.get("allow"), "POST")
        status, headers, body = request(self.open_port, "PUT", "/v1/meshes")
        self.assertEqual((status, headers.get("allow")), (405, "GET, HEAD, POST"), body)
        for path in ("/three/../../../../etc/passwd", "/../../etc/passwd",
                     "/three/%2e%2e/%2e%2e/etc/passwd", "/%2e%2e/%2e%2e/etc/passwd"):
            status, _, body = request(self.open_port, "GET", path)
            self.assertEqual(status, 404, (path, body[:100]))
            self.assertNotIn(b"root:", body)


if __name__ == "__main__":
    unittest.main(argv=sys.argv[:1], verbosity=2)
