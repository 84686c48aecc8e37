#!/usr/bin/python3
"""Hostile uploads and registrations against a real daemon on 127.0.0.1.

An upload that is cancelled, cut short, too long, mis-hashed or unparsable
leaves no mesh, no catalog entry and no file in --graph-dir, and the same
upload made again succeeds. Registration opens only regular files (a FIFO is
refused at once and does not hold up SIGTERM), names and paths with NUL, "."
and ".." are refused, error messages repeat at most 80 characters of what a
client sent, and a mesh with no faces is refused. A mesh uploaded as numpy
arrays reads back equal. Request bytes that are not the message at all are
INVALID_ARGUMENT naming it.

Usage: uploads_test.py BUILD_BIN_DIR SOURCE_DIR
"""
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import unittest

import numpy as np

BIN, SRC = sys.argv[1], sys.argv[2]
sys.path.insert(0, os.path.join(SRC, "client", "python"))
import grpc  # noqa: E402
from geodesic_client import Client  # noqa: E402
from geodesic_client._stubs import pb, rpc  # noqa: E402
from daemon_ports import start_daemon  # noqa: E402
from comparisons import assert_same  # noqa: E402

with open(os.path.join(SRC, "data", "spot.obj"), "rb") as _f:
    SPOT = _f.read()
MAX_UPLOAD = 1_000_000
INVALID = grpc.StatusCode.INVALID_ARGUMENT


def header(name, payload, fmt="obj", **overrides):
    fields = dict(name=name, format=fmt, total_bytes=len(payload),
                  sha256=hashlib.sha256(payload).hexdigest())
    fields.update(overrides)
    return fields


def messages(name, payload, chunk=64 << 10, **overrides):
    """The messages of an upload of payload, declared as header() says."""
    first = True
    for start in range(0, max(len(payload), 1), chunk):
        data = payload[start:start + chunk]
        yield pb.UploadMeshRequest(data=data, **(header(name, payload, **overrides)
                                                 if first else {}))
        first = False


def spot_arrays():
    vertices, faces = [], []
    for line in SPOT.decode().splitlines():
        parts = line.split()
        if parts and parts[0] == "v":
            vertices.append([float(x) for x in parts[1:4]])
        elif parts and parts[0] == "f":
            faces.append([int(x.split("/")[0]) - 1 for x in parts[1:4]])
    return np.array(vertices), np.array(faces, dtype=np.int64)


class UploadsTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.work = tempfile.mkdtemp()
        cls.graphs = os.path.join(cls.work, "graphs")
        cls.root = os.path.join(cls.work, "root")
        os.makedirs(cls.root)
        shutil.copy(os.path.join(SRC, "data", "spot.obj"), cls.root)
        with open(os.path.join(cls.root, "points.obj"), "w") as f:
            f.write("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
        os.mkfifo(os.path.join(cls.root, "pipe.obj"))
        cls.daemon, ports = start_daemon(
            BIN, cls.work, ["--graph-dir", cls.graphs, "--mesh-root", cls.root, "--no-sample",
                            "--max-upload-bytes", str(MAX_UPLOAD), "--log-level", "warning"])
        cls.address = f"127.0.0.1:{ports['grpc']}"
        cls.channel = grpc.insecure_channel(cls.address)
        cls.stub = rpc.GeodesicStub(cls.channel)
        cls.client = Client(f"127.0.0.1:{ports['grpc']}", timeout=60)
        for _ in range(100):
            try:
                cls.client.meshes()
                break
            except grpc.RpcError:
                time.sleep(0.1)

    @classmethod
    def tearDownClass(cls):
        cls.client.close()
        cls.channel.close()
        cls.daemon.kill()
        cls.daemon.wait(timeout=30)
        shutil.rmtree(cls.work)

    # -- helpers ----------------------------------------------------------------

    def files(self):
        return set(os.listdir(self.graphs)) if os.path.isdir(self.graphs) else set()

    def catalogued(self):
        path = os.path.join(self.graphs, "catalog.json")
        if not os.path.exists(path):
            return set()
        with open(path) as f:
            return {m["name"] for m in json.load(f).get("meshes", [])}

    def assert_no_trace(self, name, files_before):
        # Today's torn uploads are registered once the server sees the
        # stream end: give it the moment that takes.
        time.sleep(0.5)
        self.assertNotIn(name, [m.name for m in self.client.meshes()])
        self.assertNotIn(name, self.catalogued())
        self.assertEqual(self.files(), files_before)

    def upload(self, requests, timeout=30):
        return self.stub.UploadMesh(requests, timeout=timeout)

    def assert_refused(self, code, run, pattern=None):
        with self.assertRaises(grpc.RpcError) as e:
            run()
        self.assertEqual(e.exception.code(), code, e.exception.details())
        if pattern:
            self.assertRegex(e.exception.details(), pattern)
        return e.exception.details()

    def assert_retry_works(self, name):
        m = self.upload(messages(name, SPOT))
        self.assertEqual((m.name, m.diagnostics.vertices), (name, 2930))
        self.assertIn(name, self.catalogued())
        self.client.unload_mesh(name)

    # -- torn uploads -------------------------------------------------------------

    def test_cancelled_upload_leaves_nothing_and_its_retry_works(self):
        before = self.files()
        sent, release = threading.Event(), threading.Event()

        def third_then_wait():
            yield pb.UploadMeshRequest(data=SPOT[:len(SPOT) // 3], **header("torn", SPOT))
            sent.set()
            release.wait(10)

        call = self.stub.UploadMesh.future(third_then_wait(), timeout=30)
        self.assertTrue(sent.wait(10))
        time.sleep(0.3)  # the server has read the third
        call.cancel()
        release.set()
        self.assertEqual(call.code(), grpc.StatusCode.CANCELLED)
        self.assert_no_trace("torn", before)
        self.assert_retry_works("torn")

    def test_wrong_checksum_leaves_nothing(self):
        before = self.files()
        wrong = hashlib.sha256(SPOT + b"\n").hexdigest()
        self.assert_refused(INVALID, lambda: self.upload(messages("hashed", SPOT, sha256=wrong)),
                            "SHA-256")
        self.assert_no_trace("hashed", before)
        self.assert_retry_works("hashed")

    def test_wrong_size_leaves_nothing(self):
        before = self.files()
        self.assert_refused(INVALID, lambda: self.upload(
            messages("sized", SPOT, total_bytes=len(SPOT) + 100)), "ended after")
        self.assert_refused(INVALID, lambda: self.upload(
            messages("sized", SPOT, total_bytes=len(SPOT) - 100)), "more than")
        self.assert_no_trace("sized", before)
        self.assert_retry_works("sized")

    def test_more_than_declared_is_refused_at_once(self):
        release = threading.Event()

        def overflow_then_wait():
            yield pb.UploadMeshRequest(data=SPOT[:200], **header("over", SPOT[:100]))
            release.wait(10)

        start = time.monotonic()
        try:
            self.assert_refused(INVALID, lambda: self.upload(overflow_then_wait()), "more than")
        finally:
            release.set()
        self.assertLess(time.monotonic() - start, 5)

    def test_over_the_limit_is_refused_from_the_first_message(self):
        release = threading.Event()

        def declare_then_wait():
            yield pb.UploadMeshRequest(**header("huge", SPOT, total_bytes=2 * MAX_UPLOAD))
            release.wait(10)

        start = time.monotonic()
        try:
            self.assert_refused(grpc.StatusCode.RESOURCE_EXHAUSTED,
                                lambda: self.upload(declare_then_wait()), "max-upload-bytes")
        finally:
            release.set()
        self.assertLess(time.monotonic() - start, 5)

    def test_unparsable_bytes_leave_nothing(self):
        before = self.files()
        junk = b"this is not a mesh\n" * 100
        self.assert_refused(INVALID, lambda: self.upload(messages("junk", junk)))
        truncated = b"OFF\n3 1 0\n0 0 0\n1 0 0\n"
        self.assert_refused(INVALID, lambda: self.upload(messages("junk", truncated, fmt="off")))
        self.assert_no_trace("junk", before)
        self.assert_retry_works("junk")

    def test_a_message_that_does_not_parse_ends_nothing_registered(self):
        before = self.files()
        raw = self.channel.stream_unary("/geodesic.v1.Geodesic/UploadMesh",
                                        request_serializer=None,
                                        response_deserializer=pb.Mesh.FromString)
        first = pb.UploadMeshRequest(data=SPOT[:len(SPOT) // 3], **header("garbled", SPOT))
        # Field 3 (data) claiming more bytes than follow: no protobuf parser
        # accepts it.
        garbled = b"\x1a\xff\xff\xff\x07abc"
        self.assert_refused(INVALID, lambda: raw(iter([first.SerializeToString(), garbled]),
                                                 timeout=30))
        self.assert_no_trace("garbled", before)
        self.assert_retry_works("garbled")

    def test_a_request_that_does_not_parse_is_the_clients_error(self):
        # gRPC's own deserializer answers INTERNAL, the server's fault to a
        # client; the daemon's answers INVALID_ARGUMENT naming the message.
        garbled = b"\x1a\xff\xff\xff\x07abc"
        for method, message in [("RegisterMesh", "RegisterMeshRequest"),
                                ("Distance", "DistanceRequest"),
                                ("Matrix", "MatrixRequest")]:
            raw = self.channel.unary_unary(f"/geodesic.v1.Geodesic/{method}",
                                           request_serializer=None,
                                           response_deserializer=None)
            self.assert_refused(INVALID, lambda: raw(garbled, timeout=30),
                                f"malformed geodesic.v1.{message}")
        streamed = self.channel.unary_stream("/geodesic.v1.Geodesic/DistanceField",
                                             request_serializer=None,
                                             response_deserializer=None)
        self.assert_refused(INVALID, lambda: list(streamed(garbled, timeout=30)),
                            "malformed geodesic.v1.DistanceFieldRequest")
        self.assert_retry_works("after-garbled")  # and the daemon keeps serving

    def test_a_taken_name_leaves_no_file(self):
        self.upload(messages("taken", SPOT))
        before = self.files()
        triangle = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
        self.assert_refused(grpc.StatusCode.ALREADY_EXISTS,
                            lambda: self.upload(messages("taken", triangle)))
        self.assertEqual(self.files(), before)
        self.client.unload_mesh("taken")

    def test_undeclared_uploads_name_the_missing_field(self):
        self.assert_refused(INVALID, lambda: self.upload(
            iter([pb.UploadMeshRequest(name="old", format="obj", data=SPOT)])), "total_bytes")
        self.assert_refused(INVALID, lambda: self.upload(iter([pb.UploadMeshRequest(
            name="old", format="obj", data=SPOT, total_bytes=len(SPOT))])), "sha256")
        self.assertNotIn("old", [m.name for m in self.client.meshes()])

    def test_clients_upload_whole_files(self):
        m = self.client.upload_mesh("by-python", os.path.join(SRC, "data", "spot.obj"))
        self.assertEqual(m.diagnostics.vertices, 2930)
        self.client.unload_mesh("by-python")
        cli = subprocess.run(
            [f"{BIN}/geodesic", "--server", self.client_address(), "--mesh", "by-cli", "--json",
             "load", "--upload", os.path.join(SRC, "data", "spot.obj")],
            capture_output=True, text=True, timeout=60)
        self.assertEqual(cli.returncode, 0, cli.stderr)
        self.assertEqual(json.loads(cli.stdout)["diagnostics"]["vertices"], 2930)
        self.client.unload_mesh("by-cli")

    def client_address(self):
        return self.address

    # -- files and names ----------------------------------------------------------

    def register(self, name, path, timeout=10):
        return self.stub.RegisterMesh(pb.RegisterMeshRequest(name=name, path=path),
                                      timeout=timeout)

    def test_a_fifo_is_refused_at_once(self):
        start = time.monotonic()
        self.assert_refused(INVALID, lambda: self.register("pipe", "pipe.obj", timeout=5),
                            "pipe.obj.*FIFO")
        self.assertLess(time.monotonic() - start, 1)
        # The name is not held: a regular file registers under it at once.
        self.assertEqual(self.register("pipe", "spot.obj").diagnostics.vertices, 2930)
        self.client.unload_mesh("pipe")

    def test_names_and_paths_that_mean_something_else_are_refused(self):
        before = {m.name for m in self.client.meshes()}
        for name in (".", "..", "sp\0t"):
            self.assert_refused(INVALID, lambda: self.register(name, "spot.obj"))
            self.assert_refused(INVALID, lambda: self.upload(messages(name, SPOT)))
        self.assert_refused(INVALID, lambda: self.register("dot", "."), "is a directory")
        self.assert_refused(INVALID, lambda: self.register("nul", "spot.obj\0.txt"), "NUL")
        self.assertEqual({m.name for m in self.client.meshes()}, before)

    def test_errors_repeat_at_most_80_characters_of_the_input(self):
        # An answer repeating 10 KB would not even reach the client: gRPC
        # refuses trailers that large, and the client sees RESOURCE_EXHAUSTED
        # about metadata instead of the server's code.
        invalid, not_found = {INVALID}, {grpc.StatusCode.NOT_FOUND}
        for size in (1000, 10240):
            long = "n" * size
            for codes, run in (
                    (invalid, lambda: self.register(long, "spot.obj")),
                    (invalid, lambda: self.register("long", long)),
                    # No such directory, or a path too long to open.
                    (invalid | not_found, lambda: self.register("long", "sub/" + long)),
                    (invalid, lambda: self.upload(messages(long, SPOT))),
                    (invalid, lambda: self.upload(messages("long", SPOT, format=long))),
                    (not_found, lambda: self.stub.GetMesh(pb.GetMeshRequest(name=long),
                                                          timeout=10)),
                    (not_found, lambda: self.stub.UnloadMesh(pb.UnloadMeshRequest(name=long),
                                                             timeout=10))):
                with self.assertRaises(grpc.RpcError) as e:
                    run()
                details = e.exception.details()
                self.assertIn(e.exception.code(), codes, details)
                self.assertNotIn("n" * 81, details)
                self.assertLess(len(details), 400, details)

    def test_a_mesh_with_no_faces_is_refused(self):
        before = self.files()
        self.assert_refused(INVALID, lambda: self.register("points", "points.obj"), "no faces")
        with open(os.path.join(self.root, "points.obj"), "rb") as f:
            points = f.read()
        self.assert_refused(INVALID, lambda: self.upload(messages("points", points)), "no faces")
        self.assert_no_trace("points", before)
        # Offline, the file's diagnostics are still reported, with a failing exit code.
        info = subprocess.run([f"{BIN}/geodesicd", "info", "--json",
                               os.path.join(self.root, "points.obj")],
                              capture_output=True, text=True, timeout=60)
        self.assertNotEqual(info.returncode, 0)
        report = json.loads(info.stdout)
        self.assertEqual((report["vertices"], report["faces"]), (3, 0))
        self.assertIn("no faces", report["mesh_error"])

    # -- arrays ---------------------------------------------------------------------

    def test_arrays_upload_and_read_back_equal(self):
        vertices, faces = spot_arrays()
        m = self.client.upload_mesh("arrays", vertices=vertices, faces=faces)
        self.assertEqual((m.diagnostics.vertices, m.diagnostics.faces), (len(vertices), len(faces)))
        v, f = self.client.geometry("arrays")
        self.assertEqual((v.dtype, f.dtype), (np.float64, np.uint32))
        assert_same(v, vertices)
        assert_same(f, faces)
        # The same mesh as the file it came from.
        from_file = self.upload(messages("arrays-file", SPOT))
        self.assertEqual(m.fingerprint, from_file.fingerprint)
        self.assertIn("arrays", self.catalogued())
        for name in ("arrays", "arrays-file"):
            self.client.unload_mesh(name)

    def test_arrays_with_a_wrong_checksum_leave_nothing(self):
        before = self.files()
        vertices, faces = spot_arrays()
        flat_v = vertices.reshape(-1).tolist()
        flat_f = faces.reshape(-1).tolist()
        total = 8 * len(flat_v) + 4 * len(flat_f)
        requests = [pb.UploadMeshRequest(name="bad-arrays", total_bytes=total, sha256="0" * 64),
                    pb.UploadMeshRequest(vertices=flat_v), pb.UploadMeshRequest(faces=flat_f)]
        self.assert_refused(INVALID, lambda: self.upload(iter(requests)), "SHA-256")
        self.assert_no_trace("bad-arrays", before)


class ShutdownTest(unittest.TestCase):
    def test_sigterm_completes_after_a_fifo_was_offered(self):
        work = tempfile.mkdtemp()
        try:
            root = os.path.join(work, "root")
            os.makedirs(root)
            os.mkfifo(os.path.join(root, "pipe.obj"))
            daemon, ports = start_daemon(BIN, work, ["--graph-dir", os.path.join(work, "graphs"),
                                                     "--mesh-root", root, "--no-sample",
                                                     "--log-level", "warning"])
            try:
                with grpc.insecure_channel(f"127.0.0.1:{ports['grpc']}") as channel:
                    stub = rpc.GeodesicStub(channel)
                    with self.assertRaises(grpc.RpcError) as e:
                        stub.RegisterMesh(pb.RegisterMeshRequest(name="pipe", path="pipe.obj"),
                                          timeout=3)
                    self.assertEqual(e.exception.code(), INVALID)
                daemon.send_signal(signal.SIGTERM)
                self.assertIsNotNone(_wait(daemon, 5), "geodesicd did not stop on SIGTERM")
            finally:
                if daemon.poll() is None:
                    daemon.kill()
                    daemon.wait(timeout=30)
        finally:
            shutil.rmtree(work)


def _wait(process, seconds):
    try:
        return process.wait(timeout=seconds)
    except subprocess.TimeoutExpired:
        return None


if __name__ == "__main__":
    unittest.main(argv=[sys.argv[0], "-v"])
