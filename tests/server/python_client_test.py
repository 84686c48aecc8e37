#!/usr/bin/python3
"""Tests of the Python client against a real daemon on 127.0.0.1.

Usage: python_client_test.py BUILD_BIN_DIR SOURCE_DIR
"""
import concurrent.futures
import dataclasses
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import tomllib
import typing
import unittest

import numpy as np

BIN, SRC = sys.argv[1], sys.argv[2]
sys.path.insert(0, os.path.join(SRC, "client", "python"))
import grpc  # noqa: E402
import geodesic_client  # noqa: E402
from geodesic_client import (Client, GeodesicError, Graph, GraphCertificate,  # noqa: E402
                             GraphState, Mesh, MeshDiagnostics, MeshSolver, Path, VertexCopy)
from geodesic_client._stubs import pb, rpc  # noqa: E402
import daemon_ports  # noqa: E402
from daemon_ports import start_daemon  # noqa: E402
from comparisons import assert_close, assert_same  # noqa: E402


def wait_until(read, ok, timeout=60):
    """read() until ok(value), for at most `timeout` seconds; the last value."""
    deadline = time.monotonic() + timeout
    value = read()
    while not ok(value):
        if time.monotonic() > deadline:
            raise AssertionError(f"still {value!r} after {timeout} s")
        time.sleep(0.05)
        value = read()
    return value


# The requests that name a graph, and the answers that echo the graph that
# answered (None: the answer is a Graph, which names it in its own fields).
GRAPH_CALLS = {
    "RequestGraph": (pb.RequestGraphRequest, None),
    "GetGraph": (pb.GetGraphRequest, None),
    "WatchGraph": (pb.GetGraphRequest, None),
    "CancelGraph": (pb.CancelGraphRequest, None),
    "DistanceField": (pb.DistanceFieldRequest, pb.DistanceFieldChunk),
    "Distance": (pb.DistanceRequest, pb.DistanceResponse),
    "Matrix": (pb.MatrixRequest, pb.MatrixResponse),
    "MatrixRows": (pb.MatrixRequest, pb.MatrixRowsChunk),
    "SamplePoints": (pb.SamplePointsRequest, pb.SamplePointsResponse),
}


class RecordingProxy(grpc.GenericRpcHandler):
    """A gRPC server on 127.0.0.1 that passes every geodesic.v1 call on to a daemon as raw
    bytes and keeps each call's request and answers: what a client sent, as the daemon got
    it, and what the daemon said."""
    SERVER_STREAMS = {"WatchGraph", "DistanceField", "MatrixRows", "GetGeometry"}

    def __init__(self, target):
        self.calls = []  # (method name, request bytes, [answer bytes])
        self._channel = grpc.insecure_channel(target)
        self._server = grpc.server(concurrent.futures.ThreadPoolExecutor(max_workers=4))
        self._server.add_generic_rpc_handlers([self])
        self.port = self._server.add_insecure_port("127.0.0.1:0")
        self._server.start()

    def stop(self):
        self._server.stop(grace=None)
        self._channel.close()

    def take(self):
        calls, self.calls = self.calls, []
        return calls

    def service(self, details):
        if not details.method.startswith("/geodesic.v1.Geodesic/"):
            return None
        name = details.method.rsplit("/", 1)[1]
        if name in self.SERVER_STREAMS:
            forward = self._channel.unary_stream(details.method)

            def stream(request, context):
                answers = []
                self.calls.append((name, request, answers))
                try:
                    for answer in forward(request, timeout=120):
                        answers.append(answer)
                        yield answer
                except grpc.RpcError as e:
                    context.abort(e.code(), e.details())
            return grpc.unary_stream_rpc_method_handler(stream)
        forward = self._channel.unary_unary(details.method)

        def unary(request, context):
            answers = []
            self.calls.append((name, request, answers))
            try:
                answers.append(forward(request, timeout=120))
            except grpc.RpcError as e:
                context.abort(e.code(), e.details())
            return answers[0]
        return grpc.unary_unary_rpc_method_handler(unary)


class OlderServer:
    """A stub as a server older than packed matrices answers: it never sees the request's new
    fields (dtype, radius, all_sources, all_targets), so it answers float64 distances."""

    def __init__(self, stub):
        self._stub = stub
        self.requests = []

    def __getattr__(self, name):
        return getattr(self._stub, name)

    def _old(self, req):
        old = pb.MatrixRequest()
        old.CopyFrom(req)
        for field in ("dtype", "radius", "all_sources", "all_targets"):
            old.ClearField(field)
        self.requests.append(req)
        return old

    def Matrix(self, req, **kw):
        return self._stub.Matrix(self._old(req), **kw)

    def MatrixRows(self, req, **kw):
        return self._stub.MatrixRows(self._old(req), **kw)


def thresholded(dense, radius):
    """(indptr, indices, values) of the entries of `dense` within `radius`, zeros kept."""
    rows, cols = np.nonzero(dense <= radius)
    indptr = np.zeros(dense.shape[0] + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows, minlength=dense.shape[0]), out=indptr[1:])
    return indptr, cols, dense[rows, cols]


class ClientTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.work = tempfile.mkdtemp()
        cls.daemon, ports = start_daemon(
            BIN, cls.work, ["--graph-dir", f"{cls.work}/graphs", "--mesh-root", f"{SRC}/data",
                            "--log-level", "warning", "--pseudo-vertex-limit", "0"])
        cls.port = ports["grpc"]
        cls.client = Client(f"127.0.0.1:{cls.port}", timeout=120)
        for _ in range(100):
            try:
                cls.client.meshes()
                break
            except grpc.RpcError:
                time.sleep(0.1)
        cls.graph = cls.client.request_graph("spot", epsilon=0.01, wait=True)

    @classmethod
    def tearDownClass(cls):
        cls.client.close()
        daemon_ports.stop(cls.daemon)
        shutil.rmtree(cls.work)

    def graph_file(self, pseudo_vertices=False):
        # Spot's own: other tests register meshes (regions) with graphs at 0.01 too.
        spot = next(m.fingerprint for m in self.client.meshes() if m.name == "spot")
        return [f for f in os.listdir(f"{self.work}/graphs")
                if f.startswith(spot) and "eps0.01-" in f and f.endswith(".dgg")
                and ("-pseudo" in f) == pseudo_vertices][0]

    def test_field_is_a_numpy_array_equal_to_the_offline_field(self):
        field = self.client.field("spot", ["v:3"], epsilon=0.01)
        self.assertEqual(field.shape, (2930,))
        self.assertEqual(field[3], 0)
        out = f"{self.work}/offline.f64"
        subprocess.run([f"{BIN}/geodesicd", "field", "--mesh", f"{SRC}/data/spot.obj", "--graph",
                        f"{self.work}/graphs/{self.graph_file()}", "--source", "v:3", "--out", out],
                       check=True, capture_output=True)
        assert_same(field, np.fromfile(out))

    def exact_field(self, source):
        out = f"{self.work}/exact-{source.replace(':', '_')}.f64"
        subprocess.run([f"{BIN}/geodesicd", "exact", "--mesh", f"{SRC}/data/spot.obj", "--source",
                        source, "--out", out], check=True, capture_output=True)
        return np.fromfile(out)

    def test_distance_path_and_matrix_agree(self):
        eps = 0.01
        # The matrix comes from label-correcting fields, the pairs from bidirectional search:
        # two searches of one graph that find one path and sum its hops in one order, so they
        # agree to the last bit; both lie within [exact, (1 + eps) exact].
        targets = (100, 200, 300)
        m = self.client.matrix("spot", ["v:0", "v:10"], [f"v:{t}" for t in targets], epsilon=eps)
        self.assertEqual(m.shape, (2, 3))
        truth = self.exact_field("v:0")
        for j, target in enumerate(targets):
            pair = self.client.distance("spot", "v:0", f"v:{target}", epsilon=eps)
            self.assertEqual(m[0, j], pair, msg=f"v:0 -> v:{target}")
            self.assertGreaterEqual(pair, truth[target] * (1 - 1e-9))
            self.assertLessEqual(pair, truth[target] * (1 + eps))
        pair = self.client.distance("spot", "v:10", "v:300", epsilon=eps)
        self.assertEqual(m[1, 2], pair, msg="v:10 -> v:300")

        # A path's length is its polyline's: never above the graph distance (1e-6 relative
        # for float32 edge weights), never below the exact distance, so the two agree within
        # eps of the exact distance. The pair's distance is the same with or without it.
        source = "f:0:0.2,0.3,0.5"
        d = self.client.distance("spot", source, "v:1500", epsilon=eps)
        path = self.client.path("spot", source, "v:1500", epsilon=eps)
        length = path.length
        exact = self.exact_field(source)[1500]
        self.assertGreater(exact, 0)
        self.assertEqual(path.points[-1], "v:1500")
        self.assertEqual(path.xyz.shape, (len(path.points), 3))
        self.assertLessEqual(length, d * (1 + 1e-6))
        self.assertGreaterEqual(length, exact * (1 - 1e-9))
        self.assertLessEqual(d, exact * (1 + eps))
        self.assertAlmostEqual(length, d, delta=eps * exact)
        with_path, _ = self.client.distances("spot", [source], ["v:1500"], epsilon=eps,
                                             with_path=True)
        self.assertEqual(float(with_path[0]), d)

    def test_exact_pairs_paths_and_rows_equal_the_exact_engine(self):
        # exact=True: the exact engine's distance through the daemon, to rounding, for a face
        # point and a vertex, with the exact geodesic as its path; exact matrix rows agree.
        # The first exact answer also starts the graph's exact landmarks (the daemon's default
        # --exact-landmarks 128: 4 bytes per vertex each, and 64 per half-edge for the face
        # frames exact pairs then read) in the background; answers after them are the same.
        eps, source = 0.01, "f:0:0.2,0.3,0.5"
        truth = self.exact_field(source)
        targets = (1500, 700)
        self.client.request_graph("spot", epsilon=eps, wait=True)
        before = wait_until(lambda: self.client.graph("spot", epsilon=eps).landmark_bytes,
                            lambda b: b > 0)
        for target in targets:
            got = self.client.distance("spot", source, f"v:{target}", epsilon=eps, exact=True)
            self.assertTrue(np.isfinite(got) and np.isfinite(truth[target]))
            self.assertAlmostEqual(got, truth[target], delta=1e-12 * truth[target])
        spot = self.client.mesh("spot")
        exact_landmark_bytes = (spot.diagnostics.vertices * 128 * 4 +
                                spot.diagnostics.faces * 3 * 64)
        wait_until(lambda: self.client.graph("spot", epsilon=eps).landmark_bytes,
                   lambda b: b == before + exact_landmark_bytes)
        for target in targets:
            got = self.client.distance("spot", source, f"v:{target}", epsilon=eps, exact=True)
            self.assertAlmostEqual(got, truth[target], delta=1e-12 * truth[target])
        path = self.client.path("spot", source, "v:1500", epsilon=eps, exact=True)
        self.assertGreater(len(path.points), 1)
        self.assertAlmostEqual(path.length, truth[1500], delta=1e-9 * truth[1500])
        m = self.client.matrix("spot", [source], [f"v:{t}" for t in targets], epsilon=eps,
                               exact=True)
        assert_close(m[0], [truth[t] for t in targets], rtol=1e-12)
        graph_only = self.client.matrix("spot", [source], [f"v:{t}" for t in targets],
                                        epsilon=eps)
        self.assertTrue(np.all(m[0] <= graph_only[0] * (1 + 1e-12)))

    def test_packed_matrices_equal_the_float64_answer_bit_for_bit(self):
        sources, targets = [0, 10, "f:0:0.2,0.3,0.5"], [100, 200, 0, "e:40:0.3"]
        raw = rpc.GeodesicStub(self.client._channel)
        req = pb.MatrixRequest(graph=pb.GraphSelector(mesh="spot", epsilon=0.01),
                               sources=self.client._resolve("spot", sources),
                               targets=self.client._resolve("spot", targets))
        doubles = np.array(raw.Matrix(req, timeout=60).distances, dtype=np.float64)
        self.assertEqual(doubles.size, 12)
        self.assertTrue(np.isfinite(doubles).all())
        want = doubles.reshape(3, 4)
        old = self.client.matrix("spot", sources, targets, epsilon=0.01)  # the old call
        self.assertEqual((old.dtype, old.shape), (np.float64, (3, 4)))
        self.assertEqual(old.tobytes(), want.tobytes())
        for dtype in (np.float32, np.float64):
            got = self.client.matrix("spot", sources, targets, epsilon=0.01, dtype=dtype)
            self.assertEqual((got.dtype, got.shape), (np.dtype(dtype), (3, 4)))
            self.assertEqual(got.tobytes(), want.astype(dtype).tobytes(), dtype)
            # The streamed form's packed rows too.
            req.dtype = pb.MATRIX_DTYPE_FLOAT32 if dtype is np.float32 else pb.MATRIX_DTYPE_FLOAT64
            chunks = list(raw.MatrixRows(req, timeout=60))
            self.assertTrue(all(c.dtype == req.dtype and not c.distances for c in chunks))
            self.assertEqual(b"".join(c.packed for c in chunks), want.astype(dtype).tobytes())

    def test_whole_mesh_matrices_equal_the_vertex_lists(self):
        n = self.client.mesh("spot").diagnostics.vertices
        self.assertEqual(n, 2930)
        targets = [0, 1500, 2929, "f:5:0.3,0.3,0.4"]
        listed = self.client.matrix("spot", np.arange(n), targets, epsilon=0.01)
        self.assertEqual(listed.shape, (n, 4))
        self.assertTrue(np.isfinite(listed).all())
        whole = self.client.matrix("spot", None, targets, epsilon=0.01, dtype=np.float64)
        self.assertEqual(whole.tobytes(), listed.tobytes())
        # The whole-mesh form defaults to float32.
        narrow = self.client.matrix("spot", None, targets, epsilon=0.01)
        self.assertEqual(narrow.dtype, np.float32)
        self.assertEqual(narrow.tobytes(), listed.astype(np.float32).tobytes())
        rows = self.client.matrix("spot", [7, 1500], None, epsilon=0.01, dtype=np.float64)
        self.assertEqual(rows.shape, (2, n))
        self.assertEqual(rows.tobytes(), self.client.matrix(
            "spot", [7, 1500], np.arange(n), epsilon=0.01).tobytes())
        self.assertEqual(rows[0, 7], 0)

    def test_matrix_into_a_npy_file_and_an_array(self):
        n = 2930
        path = f"{self.work}/all.npy"
        got = self.client.matrix("spot", epsilon=0.01, out=path)  # every vertex x every vertex
        self.assertIsInstance(got, np.memmap)
        del got
        m = np.load(path, mmap_mode="r")
        self.assertEqual((m.dtype, m.shape), (np.float32, (n, n)))
        self.assertTrue(np.isfinite(m).all())
        self.assertTrue((np.diag(m) == 0).all())
        some = [0, 999, 2929]
        want = self.client.matrix("spot", some, np.arange(n), epsilon=0.01)
        self.assertTrue(np.isfinite(want).all())
        self.assertEqual(np.asarray(m[some]).tobytes(), want.astype(np.float32).tobytes())
        # Into the caller's array, whose dtype it takes.
        out = np.full((3, n), np.nan, dtype=np.float64)
        self.assertIs(self.client.matrix("spot", some, None, epsilon=0.01, out=out), out)
        self.assertEqual(out.tobytes(), want.tobytes())
        with self.assertRaisesRegex(ValueError, "writable"):
            self.client.matrix("spot", some, None, epsilon=0.01, out=np.empty((2, n)))
        with self.assertRaisesRegex(ValueError, "float16"):
            self.client.matrix("spot", some, [0], epsilon=0.01, dtype=np.float16)

    def test_neighbourhood_matrix_is_the_thresholded_dense_matrix(self):
        import scipy.sparse
        sources = np.arange(0, 2930, 7)
        dense = self.client.matrix("spot", sources, None, epsilon=0.01, dtype=np.float64)
        self.assertTrue(np.isfinite(dense).all())
        radius = float(np.quantile(dense, 0.1))
        indptr, indices, values = thresholded(dense, radius)
        self.assertTrue(0 < values.size < dense.size / 5)
        for dtype in (np.float64, np.float32):
            got = self.client.neighbourhood_matrix("spot", radius, sources, epsilon=0.01,
                                                   dtype=dtype)
            self.assertIsInstance(got, scipy.sparse.csr_matrix)
            self.assertEqual((got.shape, got.dtype), (dense.shape, np.dtype(dtype)))
            self.assertEqual(got.indptr.tolist(), indptr.tolist())
            self.assertEqual(got.indices.tolist(), indices.tolist())
            self.assertEqual(got.data.tobytes(), values.astype(dtype).tobytes())
        whole = self.client.neighbourhood_matrix("spot", radius, epsilon=0.01)
        self.assertEqual(whole.shape, (2930, 2930))
        self.assertEqual(whole.dtype, np.float32)
        rows = whole[sources]
        self.assertEqual(rows.nnz, got.nnz)
        self.assertEqual(rows.toarray().tobytes(), got.toarray().tobytes())
        self.assertEqual(whole.diagonal().tolist(), [0] * 2930)
        self.assertEqual(whole.indptr[-1], whole.nnz)
        for radius in (0, -1, float("nan"), float("inf")):
            with self.assertRaisesRegex(ValueError, "radius"):
                self.client.neighbourhood_matrix("spot", radius)

    def test_bad_radius_and_conflicting_selectors_are_refused_by_name(self):
        raw = rpc.GeodesicStub(self.client._channel)
        graph = pb.GraphSelector(mesh="spot", epsilon=0.01)
        for radius, text in ((-1.0, "radius -1"), (float("nan"), "radius nan"),
                             (float("inf"), "radius inf")):
            with self.assertRaises(grpc.RpcError) as e:
                list(raw.MatrixRows(pb.MatrixRequest(graph=graph, all_targets=True,
                                                     sources=[pb.SurfacePoint(vertex=0)],
                                                     radius=radius), timeout=60))
            self.assertEqual(e.exception.code(), grpc.StatusCode.INVALID_ARGUMENT)
            self.assertIn(text, e.exception.details())
        with self.assertRaises(grpc.RpcError) as e:
            list(raw.MatrixRows(pb.MatrixRequest(graph=graph, all_sources=True,
                                                 sources=[pb.SurfacePoint(vertex=0)],
                                                 targets=[pb.SurfacePoint(vertex=1)]),
                                timeout=60))
        self.assertEqual(e.exception.code(), grpc.StatusCode.INVALID_ARGUMENT)
        self.assertIn("all_sources and 1 explicit sources", e.exception.details())
        # Matrix keeps its limits, the whole mesh counted as its vertices.
        with self.assertRaises(grpc.RpcError) as e:
            raw.Matrix(pb.MatrixRequest(graph=graph, all_sources=True, all_targets=True),
                       timeout=60)
        self.assertEqual(e.exception.code(), grpc.StatusCode.RESOURCE_EXHAUSTED)
        self.assertIn("matrix of 2930 x 2930 exceeds the limits (1024 sources, 10000 targets)",
                      e.exception.details())

    def test_an_older_server_is_read_through_its_float64_answers(self):
        targets = [0, 1500, "f:5:0.3,0.3,0.4"]
        want = self.client.matrix("spot", None, targets, epsilon=0.01, dtype=np.float64)
        self.assertTrue(np.isfinite(want).all())
        radius = float(np.quantile(want, 0.2))
        sparse = self.client.neighbourhood_matrix("spot", radius, None, targets, epsilon=0.01)
        self.assertGreater(sparse.nnz, 0)
        with Client(f"127.0.0.1:{self.port}", timeout=120) as c:
            old = c._stub = OlderServer(c._stub)
            got = c.matrix("spot", None, targets, epsilon=0.01)
            self.assertEqual(got.dtype, np.float32)
            self.assertEqual(got.tobytes(), want.astype(np.float32).tobytes())
            self.assertTrue(old.requests[0].all_sources)  # tried, then spelt out
            self.assertFalse(old.requests[-1].all_sources)
            got_sparse = c.neighbourhood_matrix("spot", radius, None, targets, epsilon=0.01)
            self.assertEqual(got_sparse.indptr.tolist(), sparse.indptr.tolist())
            self.assertEqual(got_sparse.indices.tolist(), sparse.indices.tolist())
            self.assertEqual(got_sparse.data.tobytes(), sparse.data.tobytes())
            got = c.matrix("spot", [0, 7], targets, epsilon=0.01)
            self.assertEqual(got.tobytes(), want[[0, 7]].tobytes())

    def test_pseudo_vertex_graph_is_its_own_graph(self):
        # Requested with wait, the client watches the pseudo graph, not the plain one.
        g = self.client.request_graph("spot", epsilon=0.01, wait=True, pseudo_vertices=True)
        self.assertEqual(g.state, GraphState.READY)
        self.assertTrue(g.pseudo_vertices)
        self.assertGreater(g.nodes, 2930)
        plain = self.client.graph("spot", epsilon=0.01)
        self.assertEqual((plain.pseudo_vertices, plain.nodes), (False, 2930))
        again = self.client.graph("spot", epsilon=0.01, pseudo_vertices=True)
        self.assertEqual(again.nodes, g.nodes)
        listed = {(x.epsilon, x.pseudo_vertices) for x in self.client.graphs() if x.mesh == "spot"}
        self.assertLessEqual({(0.01, False), (0.01, True)}, listed)

        # Its answers are those of its file, queried offline.
        graph = f"{self.work}/graphs/{self.graph_file(pseudo_vertices=True)}"
        field = self.client.field("spot", ["v:3"], epsilon=0.01, pseudo_vertices=True)
        out = f"{self.work}/offline-pseudo.f64"
        subprocess.run([f"{BIN}/geodesicd", "field", "--mesh", f"{SRC}/data/spot.obj", "--graph",
                        graph, "--source", "v:3", "--out", out], check=True, capture_output=True)
        assert_same(field, np.fromfile(out))
        a, b = "f:0:0.2,0.3,0.5", "v:1500"
        d = self.client.distance("spot", a, b, epsilon=0.01, pseudo_vertices=True)
        offline = subprocess.run([f"{BIN}/geodesicd", "distance", "--mesh", f"{SRC}/data/spot.obj",
                                  "--graph", graph, "--from", a, "--to", b, "--json"],
                                 check=True, capture_output=True, text=True)
        self.assertEqual(d, json.loads(offline.stdout)["distance"])
        m = self.client.matrix("spot", [a], [b], epsilon=0.01, pseudo_vertices=True)
        self.assertEqual(m[0, 0], d)
        self.assertAlmostEqual(
            self.client.path("spot", a, b, epsilon=0.01, pseudo_vertices=True).length, d,
            delta=0.01 * d)

    def test_a_region_is_a_mesh_whose_distances_stay_inside(self):
        v, f = self.client.geometry("spot")
        upper = np.flatnonzero(v[:, 1] > 0)
        self.assertTrue(0 < len(upper) < len(v), len(upper))
        region = self.client.register_region("spot-upper", "spot", vertices=upper[::-1])
        self.assertIsInstance(region, Mesh)
        self.assertEqual((region.name, region.parent, region.parent_vertices,
                          region.parent_faces), ("spot-upper", "spot", len(v), len(f)))
        self.assertEqual(self.client.mesh("spot-upper"), region)
        # Its vertices are the parent's its faces use, in the parent's order.
        inside = np.isin(f, upper).all(axis=1)
        kept = np.unique(f[inside])
        rv, rf = self.client.geometry("spot-upper")
        self.assertEqual((len(rv), len(rf)), (len(kept), int(inside.sum())))
        np.testing.assert_array_equal(rv, v[kept])
        # Paths that may not leave the region are no shorter than the whole
        # mesh's: each region distance is at least the parent's, and some are longer.
        source = int(kept[0])
        whole = self.client.field("spot", [f"v:{source}"], epsilon=0.01)
        self.client.request_graph("spot-upper", epsilon=0.01, wait=True)  # not the default ε
        part = self.client.field("spot-upper", ["v:0"], epsilon=0.01)
        self.assertEqual(part.shape, (len(kept),))
        reached = np.isfinite(part)
        self.assertGreater(reached.sum(), len(kept) // 2)
        self.assertTrue(np.isfinite(whole[kept]).all())
        self.assertTrue((part[reached] >= whole[kept][reached] * (1 - 0.02)).all())
        self.assertGreater(np.max(part[reached] - whole[kept][reached]), 0)
        by_faces = self.client.register_region("spot-upper-faces", "spot",
                                               faces=np.flatnonzero(inside))
        self.assertEqual(by_faces.fingerprint, region.fingerprint)
        with self.assertRaises(ValueError):
            self.client.register_region("x", "spot", vertices=[0], faces=[0])
        with self.assertRaises(GeodesicError) as e:
            self.client.register_region("x", "spot", vertices=[0, 10 ** 7])
        self.assertIn("10000000", str(e.exception))
        for name in ("spot-upper", "spot-upper-faces"):
            self.client.unload_mesh(name)

    def test_sample_points_cover_the_mesh(self):
        vertices, radius = self.client.sample_points("spot", 8, seed=5, epsilon=0.01)
        self.assertEqual((vertices.dtype, vertices.shape), (np.uint32, (8,)))
        self.assertEqual(len(set(vertices.tolist())), 8)
        again, _ = self.client.sample_points("spot", 8, seed=5, epsilon=0.01)
        assert_same(vertices, again)
        # The covering radius is the farthest any vertex lies from its nearest sample.
        field = self.client.field("spot", [f"v:{v}" for v in vertices], epsilon=0.01)
        self.assertAlmostEqual(radius, field.max(), delta=1e-12 * radius)
        # Each point after the first is the farthest from those before it.
        before = self.client.field("spot", [f"v:{v}" for v in vertices[:4]], epsilon=0.01)
        self.assertAlmostEqual(before[vertices[4]], before.max(), delta=1e-12 * before.max())

    def test_snap_and_positions(self):
        (snapped,) = self.client.snap("spot", [(0.1, 0.2, 0.3)])
        self.assertTrue(snapped.startswith(("f:", "e:", "v:")))
        d = self.client.distance("spot", "xyz:0.1,0.2,0.3", snapped, epsilon=0.01)
        self.assertAlmostEqual(d, 0.0, places=9)

    def test_batches_shrink_to_a_small_message_limit(self):
        # Each "larger than max" answer must shrink the next batch: it once
        # resent the same batch forever.
        rng = np.random.default_rng(3)
        faces = rng.integers(0, 5000, 200)
        bary = rng.dirichlet([1, 1, 1], 200)
        specs = [f"f:{f}:{b[0]!r},{b[1]!r},{1 - b[0] - b[1]!r}" for f, b in zip(faces, bary)]
        want = self.client.distances("spot", specs[:100], specs[100:], epsilon=0.01)
        with Client(f"127.0.0.1:{self.port}", timeout=60, max_message_bytes=4096) as small:
            got = small.distances("spot", specs[:100], specs[100:], epsilon=0.01)
        # Equal to the last bit: a search that meets at another node (before
        # and after the landmarks are ready) still sums the path from its
        # first point.
        assert_same(got, want)

    def test_lower_server_limits_are_learnt_by_every_call(self):
        # A daemon with tighter limits than the client's defaults: matrix,
        # field and snap split their work as distances does.
        work = tempfile.mkdtemp()
        daemon, ports = start_daemon(
            BIN, work, ["--graph-dir", f"{work}/g", "--mesh-root", f"{SRC}/data", "--log-level", "error",
                        "--max-pairs", "50", "--max-sources", "4"])
        try:
            with Client(f"127.0.0.1:{ports['grpc']}", timeout=60) as tight:
                for _ in range(100):
                    try:
                        tight.meshes()
                        break
                    except grpc.RpcError:
                        time.sleep(0.1)
                tight.request_graph("spot", epsilon=0.01, wait=True)
                targets = np.arange(0, 2930, 14)[:200]
                got = tight.matrix("spot", [0, 7, 900], targets, epsilon=0.01)
                want = self.client.matrix("spot", [0, 7, 900], targets, epsilon=0.01)
                assert_same(got, want)
                sources = list(range(0, 2930, 293))  # 10
                # The minimum of three partial fields: equal up to an ulp where
                # two sources tie.
                assert_close(tight.field("spot", sources, epsilon=0.01),
                                           self.client.field("spot", sources, epsilon=0.01),
                                           rtol=1e-14)
                positions = np.random.default_rng(5).normal(size=(200, 3)) * 0.5
                self.assertEqual(tight.snap("spot", positions), self.client.snap("spot", positions))
                self.assertEqual((tight.max_pairs, tight.max_sources), (50, 4))
                # Whole-mesh selectors stream past both limits, in one request.
                whole = tight.matrix("spot", None, [0, 7], epsilon=0.01, dtype=np.float64)
                self.assertEqual(whole.tobytes(), self.client.matrix(
                    "spot", None, [0, 7], epsilon=0.01, dtype=np.float64).tobytes())
                self.assertEqual(tight.matrix("spot", [0, 7], None, epsilon=0.01).tobytes(),
                                 self.client.matrix("spot", [0, 7], None,
                                                    epsilon=0.01).tobytes())
        finally:
            daemon_ports.stop(daemon)
            shutil.rmtree(work)

    def test_an_overloaded_server_is_waited_for_unless_retries_are_off(self):
        # A daemon that admits one query at a time answers a second one, once it has waited
        # for a slot what its deadline allows, RESOURCE_EXHAUSTED "server overloaded" with a
        # retry-after-ms hint (before the deadline, not DEADLINE_EXCEEDED): a client on the default policy waits
        # and gets its answer, one with retries off gets the error. No exact landmarks: their
        # background fields would share the two cores with the slow query and stretch it past
        # the default policy's few seconds of retries.
        work = tempfile.mkdtemp()
        daemon, ports = start_daemon(
            BIN, work, ["--log-level", "error", "--max-inflight", "1", "--query-threads", "1",
                        "--exact-landmarks", "0"])
        address = f"127.0.0.1:{ports['grpc']}"
        try:
            with Client(address, timeout=120) as busy, \
                    Client(address, timeout=60) as patient, \
                    Client(address, timeout=0.5,
                           retry=geodesic_client.RetryPolicy(max_attempts=1)) as hasty:
                busy.request_graph("spot", epsilon=0.01, wait=True)
                want = patient.distance("spot", "v:0", "v:1500", epsilon=0.01)
                # Exact rows: about three seconds of them on this machine, measured here,
                # longer than the second a query waits for admission before it is refused,
                # and short enough, even with the other core busy (ctest -j2), to end within
                # the default policy's retries (each attempt waiting its second, then at
                # least about 3.5 s of backoff).
                start = time.monotonic()
                busy.matrix("spot", list(range(0, 2930, 300)), [1500, 700], epsilon=0.01,
                            exact=True)
                per_row = (time.monotonic() - start) / 10
                rows = min(2930, max(10, int(3.0 / max(per_row, 1e-6))))
                sources = list(range(0, 2930, max(1, 2930 // rows)))
                with concurrent.futures.ThreadPoolExecutor(1) as pool:
                    slow = pool.submit(busy.matrix, "spot", sources, [1500, 700], epsilon=0.01,
                                       exact=True)
                    refused = None
                    while refused is None and not slow.done():
                        try:
                            hasty.distance("spot", "v:0", "v:1500", epsilon=0.01)
                        except geodesic_client.ResourceExhaustedError as e:
                            refused = e
                    self.assertIsNotNone(refused, "the slow query ended before any overload")
                    self.assertTrue(refused.details().startswith("server overloaded"),
                                    refused.details())
                    self.assertFalse(slow.done(), "the slow query ended too soon to test")
                    self.assertEqual(patient.distance("spot", "v:0", "v:1500", epsilon=0.01),
                                     want)
                    self.assertEqual(slow.result().shape, (len(sources), 2))
        finally:
            daemon_ports.stop(daemon)
            shutil.rmtree(work)

    def test_pseudo_vertices_past_the_default_limit_are_refused_with_the_estimate(self):
        # spot would take tens of pseudo vertices per vertex at 1e-2: a daemon
        # on default flags refuses the graph, saying what it would cost, and
        # keeps serving the plain one.
        work = tempfile.mkdtemp()
        daemon, ports = start_daemon(BIN, work, ["--graph-dir", f"{work}/g", "--log-level", "error"])
        try:
            with Client(f"127.0.0.1:{ports['grpc']}", timeout=60) as c:
                with self.assertRaises(RuntimeError) as refused:
                    c.request_graph("spot", epsilon=0.01, pseudo_vertices=True)
                message = str(refused.exception)
                for part in ("FAILED", "pseudo vertices at eps 0.01", "per mesh vertex",
                             "over the limit of 1", "MB", "a quarter of this eps"):
                    self.assertIn(part, message)
                self.assertEqual(c.graph("spot", epsilon=0.01, pseudo_vertices=True).state,
                                 GraphState.FAILED)
                # Asked for: a query starts only the default epsilon's graph.
                c.request_graph("spot", epsilon=0.01, wait=True)
                d = c.distances("spot", [10], [20], epsilon=0.01)
                self.assertTrue(np.isfinite(d).all() and d[0] > 0, d)
        finally:
            daemon_ports.stop(daemon)
            shutil.rmtree(work)

    def test_one_position_is_one_source_and_a_missing_upload_names_the_file(self):
        one = self.client.field("spot", np.array([0.1, 0.2, 0.3]), epsilon=0.01)
        assert_same(
            one, self.client.field("spot", [[0.1, 0.2, 0.3]], epsilon=0.01))
        self.assertEqual(one.shape, (2930,))
        with self.assertRaises(FileNotFoundError):
            self.client.upload_mesh("ghost", f"{self.work}/no-such-file.obj")
        with self.assertRaisesRegex(ValueError, "no extension"):
            self.client.upload_mesh("ghost", f"{SRC}/README.md"[:-3])

    def test_errors_carry_codes(self):
        with self.assertRaises(grpc.RpcError) as e:
            self.client.distance("spot", "v:999999", "v:1", epsilon=0.01)
        self.assertEqual(e.exception.code(), grpc.StatusCode.OUT_OF_RANGE)
        with self.assertRaises(grpc.RpcError) as e:
            self.client.distance("nosuch", "v:1", "v:2")
        self.assertEqual(e.exception.code(), grpc.StatusCode.NOT_FOUND)
        with self.assertRaises(grpc.RpcError) as e:
            self.client.field("spot", ["f:1:0.5,0.5,0.5"], epsilon=0.01)
        self.assertEqual(e.exception.code(), grpc.StatusCode.INVALID_ARGUMENT)

    def test_upload_and_list(self):
        m = self.client.upload_mesh("copy", f"{SRC}/data/spot.obj")
        self.assertIsInstance(m, Mesh)
        self.assertEqual(m.diagnostics.vertices, 2930)
        self.assertIn("copy", [x.name for x in self.client.meshes()])

    def raw_mesh(self, name):
        """The GetMesh message itself, asked without the client."""
        with grpc.insecure_channel(f"127.0.0.1:{self.port}") as channel:
            return rpc.GeodesicStub(channel).GetMesh(pb.GetMeshRequest(name=name), timeout=60)

    def test_meshes_are_frozen_dataclasses_equal_to_the_messages(self):
        m, raw = self.client.mesh("spot"), self.raw_mesh("spot")
        self.assertIsInstance(m, Mesh)
        self.assertIsInstance(m.diagnostics, MeshDiagnostics)
        with self.assertRaises(dataclasses.FrozenInstanceError):
            m.name = "other"
        self.assertEqual((m.name, m.fingerprint, m.source, m.restored, m.repair_non_manifold),
                         (raw.name, raw.fingerprint, raw.source, raw.restored,
                          raw.repair_non_manifold))
        self.assertEqual(m.vertex_copies, ())
        d = m.diagnostics
        for f in ("vertices", "faces", "edges", "components", "boundary_loops", "genus",
                  "isolated_vertices", "non_manifold_vertices", "bbox_diagonal",
                  "anisotropy_mean", "json"):
            self.assertEqual(getattr(d, f), getattr(raw.diagnostics, f), msg=f)
        self.assertEqual((d.vertices, d.faces, d.genus), (2930, 5856, 0))
        # The full report, parsed: the typed fields are among its keys.
        self.assertEqual(d.details, json.loads(raw.diagnostics.json))
        self.assertEqual((d.details["vertices"], d.details["anisotropy_mean"]),
                         (d.vertices, d.anisotropy_mean))
        self.assertIn("zero_area_faces", d.details)
        hash(m)  # frozen and hashable, the details dict left out
        listed = {x.name: x for x in self.client.meshes()}
        self.assertTrue(all(isinstance(x, Mesh) for x in listed.values()))
        self.assertEqual(listed["spot"], m)

        registered = self.client.register_mesh("spot-repaired", "spot.obj",
                                               repair_non_manifold=True)
        self.assertIsInstance(registered, Mesh)
        self.assertEqual((registered.name, registered.repair_non_manifold,
                          registered.vertex_copies, registered.fingerprint),
                         ("spot-repaired", True, (), m.fingerprint))
        self.assertEqual(registered, self.client.mesh("spot-repaired"))
        self.assertIs(VertexCopy, geodesic_client.VertexCopy)

    def test_typed_diagnostics_equal_geodesicd_info_json(self):
        """Every key of `geodesicd info --json` is a typed field of the message, with the
        offline command's value for the bundled mesh; the client's details are built from
        them, and the superseded json field still carries the same report."""
        info = json.loads(subprocess.run(
            [f"{BIN}/geodesicd", "info", f"{SRC}/data/spot.obj", "--json"], check=True,
            capture_output=True, text=True).stdout)
        raw = self.raw_mesh("spot").diagnostics
        typed = {f.name for f in raw.DESCRIPTOR.fields} - {"json"}
        self.assertEqual(typed, set(info) - {"mesh_bytes", "usable"})
        # Where and how fast each read the file differ; everything else is equal.
        for key in sorted(typed - {"path", "load_seconds"}):
            self.assertEqual(getattr(raw, key), info[key], msg=key)
            self.assertIs(type(getattr(raw, key)), type(info[key]), msg=key)
        self.assertEqual(info["usable"], raw.mesh_error == "")
        self.assertEqual(os.path.basename(raw.path), os.path.basename(info["path"]))
        self.assertGreater(raw.load_seconds, 0)

        details = self.client.mesh("spot").diagnostics.details
        self.assertEqual(list(details), [k for k in info if k != "mesh_bytes"])
        for key in details:
            self.assertIs(type(details[key]), type(info[key]), msg=key)
            if key not in ("path", "load_seconds"):
                self.assertEqual(details[key], info[key], msg=key)
        self.assertEqual(json.loads(raw.json), details)

    def test_mesh_solver_answers_equal_the_clients(self):
        c = self.client
        solver = c.mesh_solver("spot", epsilon=0.01)
        self.assertIsInstance(solver, MeshSolver)
        self.assertEqual((solver.name, solver.epsilon, solver.pseudo_vertices),
                         ("spot", 0.01, False))
        self.assertEqual(solver.request_graph().state, GraphState.READY)
        a, b = np.array([0, 5, 17, 900]), ["v:1500", "f:0:0.2,0.3,0.5", "v:17", "v:2000"]
        kw = dict(epsilon=0.01)
        assert_same(solver.distances(a, b), c.distances("spot", a, b, **kw))
        (d1, p1), (d2, p2) = (solver.distances(a, b, with_path=True),
                              c.distances("spot", a, b, with_path=True, **kw))
        assert_same(d1, d2)
        self.assertEqual([(p.length, p.points) for p in p1], [(p.length, p.points) for p in p2])
        self.assertEqual(solver.distance(3, "v:40"), c.distance("spot", 3, "v:40", **kw))
        path, want = solver.path(3, "v:40"), c.path("spot", 3, "v:40", **kw)
        self.assertEqual((path.length, path.points), (want.length, want.points))
        assert_same(path.xyz, want.xyz)
        assert_same(solver.field([3, 700]), c.field("spot", [3, 700], **kw))
        f1, l1 = solver.field([3, 700], nearest_source=True, targets=[1, 2, 3])
        f2, l2 = c.field("spot", [3, 700], targets=[1, 2, 3], nearest_source=True, **kw)
        assert_same(f1, f2)
        assert_same(l1, l2)
        assert_same(solver.matrix([0, 1], [2, 3, 4]),
                                      c.matrix("spot", [0, 1], [2, 3, 4], **kw))
        v1, r1 = solver.sample_points(6, seed=2)
        v2, r2 = c.sample_points("spot", 6, seed=2, **kw)
        assert_same(v1, v2)
        self.assertEqual(r1, r2)
        positions = [(0.1, 0.2, 0.3), (-0.2, 0.1, 0.0)]
        self.assertEqual(solver.snap(positions), c.snap("spot", positions))
        # The clock of last use moves with every query; the rest is the same graph.
        unused = dict(last_used_unix_ms=0)
        self.assertEqual(dataclasses.replace(solver.graph(), **unused),
                         dataclasses.replace(c.graph("spot", 0.01), **unused))
        self.assertEqual(solver.mesh, c.mesh("spot"))
        self.assertIs(solver.mesh, solver.mesh)  # fetched once

        pseudo = c.mesh_solver("spot", 0.01, pseudo_vertices=True)
        self.assertTrue(pseudo.request_graph().pseudo_vertices)
        assert_same(pseudo.field([3]),
                                      c.field("spot", [3], pseudo_vertices=True, **kw))
        with Client(f"127.0.0.1:{self.port}", epsilon=0.01) as other:
            self.assertEqual(other.mesh_solver("spot").epsilon, 0.01)  # the client's default

    def test_clients_name_the_graph_in_its_selector(self):
        # The Python client and the CLI send `graph` (a GraphSelector) and leave the fields it
        # superseded unset; the daemon's answers echo the graph that answered in theirs.
        proxy = RecordingProxy(f"127.0.0.1:{self.port}")
        try:
            with Client(f"127.0.0.1:{proxy.port}", timeout=120) as c:
                c.request_graph("spot", epsilon=0.01)  # and WatchGraph
                c.graph("spot", epsilon=0.01)
                c.cancel_graph("spot", epsilon=0.01)  # ready: nothing to cancel
                c.field("spot", [3], epsilon=0.01)
                c.distances("spot", [0], [1500], epsilon=0.01)
                c.matrix("spot", [0], [1500], epsilon=0.01)
                c.sample_points("spot", 3, epsilon=0.01)
            by_client = {"python": proxy.take()}
            cli = [f"{BIN}/geodesic", "--server", f"127.0.0.1:{proxy.port}", "--mesh", "spot",
                   "--eps", "0.01"]
            for args in (["graph", "--wait"], ["graph", "--cancel"], ["field", "--source", "v:3"],
                         ["distance", "--from", "v:0", "--to", "v:1500"],
                         ["matrix", "--source", "v:0", "--target", "v:1500"],
                         ["sample", "--count", "3"]):
                run = subprocess.run(cli + args, capture_output=True, text=True)
                self.assertEqual(run.returncode, 0, f"{args}: {run.stderr}")
            by_client["cli"] = proxy.take()
        finally:
            proxy.stop()
        expected = {"python": set(GRAPH_CALLS) - {"MatrixRows"},
                    "cli": set(GRAPH_CALLS) - {"MatrixRows", "GetGraph"}}
        for client, calls in by_client.items():
            self.assertEqual({name for name, _, _ in calls} & set(GRAPH_CALLS), expected[client],
                             msg=client)
            for name, request, answers in calls:
                if name not in GRAPH_CALLS:
                    continue
                what = f"{client} {name}"
                request_type, answer_type = GRAPH_CALLS[name]
                req = request_type.FromString(request)
                self.assertTrue(req.HasField("graph"), msg=what)
                self.assertEqual((req.graph.mesh, req.graph.epsilon, req.graph.pseudo_vertices),
                                 ("spot", 0.01, False), msg=what)
                self.assertEqual((req.mesh, req.epsilon, req.pseudo_vertices), ("", 0, False),
                                 msg=what)
                if answer_type is None:
                    continue
                echo = answer_type.FromString(answers[0]).echo
                self.assertEqual((echo.graph.mesh, echo.graph.epsilon,
                                  echo.graph.pseudo_vertices), ("spot", 0.01, False), msg=what)

    def test_a_certified_graph_carries_its_certificate(self):
        g = self.client.request_graph("spot", max_error=1e-2)
        self.assertEqual(g.state, GraphState.READY)
        self.assertEqual(g.max_error, 1e-2)
        c = g.certificate
        self.assertIsInstance(c, GraphCertificate)
        self.assertTrue(c.sound)
        self.assertEqual(c.max_error_bound, 1e-2)
        self.assertLessEqual(c.measured_max_error, 1e-2)
        self.assertLessEqual(c.measured_mean_error, c.measured_max_error)
        self.assertLess(c.epsilon, 1e-2)
        self.assertEqual(g.epsilon, c.epsilon)
        self.assertGreater(c.sources, 0)
        # The same certificate from graph() and graphs(); the plain graph of
        # that epsilon is another graph, without one.
        self.assertEqual(self.client.graph("spot", max_error=1e-2).certificate, c)
        self.assertIn(c, [x.certificate for x in self.client.graphs()])
        plain = self.client.request_graph("spot", epsilon=c.epsilon)
        self.assertIsNone(plain.certificate)
        self.assertEqual(plain.max_error, 0)
        # Queries name it by its bound.
        d = self.client.distance("spot", 0, 1500, max_error=1e-2)
        self.assertTrue(np.isfinite(d) and d > 0)

    def test_progress_is_called_with_every_status_until_ready(self):
        # A fresh epsilon: this graph is built while the client waits.
        seen = []
        g = self.client.request_graph("spot", epsilon=0.05, progress=seen.append)
        self.assertGreaterEqual(len(seen), 1)
        self.assertTrue(all(isinstance(x, Graph) for x in seen))
        self.assertEqual(seen[-1].state, GraphState.READY)
        self.assertEqual(seen[-1], g)
        self.assertTrue(all(0 <= x.progress <= 1 and x.epsilon == 0.05 for x in seen))
        # Ready already: one call. Without wait: none.
        again = []
        self.client.request_graph("spot", epsilon=0.05, progress=again.append)
        self.assertEqual([x.state for x in again], [GraphState.READY])
        self.client.request_graph("spot", epsilon=0.05, wait=False, progress=again.append)
        self.assertEqual(len(again), 1)

        # A callback that raises ends the wait (the watch is cancelled).
        class Stop(Exception):
            pass

        def stop(graph):
            raise Stop

        with self.assertRaises(Stop):
            self.client.request_graph("spot", epsilon=0.05, progress=stop)

    def test_client_without_address_uses_geodesic_server(self):
        saved = os.environ.pop("GEODESIC_SERVER", None)
        try:
            with Client() as c:
                self.assertEqual(c.address, "127.0.0.1:50051")
            os.environ["GEODESIC_SERVER"] = f"127.0.0.1:{self.port}"
            with Client(timeout=60) as c:
                self.assertEqual(c.address, f"127.0.0.1:{self.port}")
                self.assertIn("spot", [m.name for m in c.meshes()])
        finally:
            os.environ.pop("GEODESIC_SERVER", None)
            if saved is not None:
                os.environ["GEODESIC_SERVER"] = saved


class PackageMetadataTest(unittest.TestCase):
    """What needs no daemon: the version's one home and the type declarations."""

    def test_version_equals_the_repositorys_version_file(self):
        with open(os.path.join(SRC, "VERSION")) as f:
            self.assertEqual(geodesic_client.__version__, f.read().strip())
        # pyproject.toml takes it from _version.py, never from a copy of its own.
        with open(os.path.join(SRC, "client", "python", "pyproject.toml"), "rb") as f:
            project = tomllib.load(f)
        self.assertNotIn("version", project["project"])
        self.assertIn("version", project["project"]["dynamic"])
        self.assertEqual(project["tool"]["setuptools"]["dynamic"]["version"],
                         {"attr": "geodesic_client._version.__version__"})
        self.assertIn("py.typed", project["tool"]["setuptools"]["package-data"]["geodesic_client"])
        self.assertTrue(os.path.isfile(os.path.join(os.path.dirname(geodesic_client.__file__),
                                                    "py.typed")))

    def returns_by_flag(self, function, flag):
        """{flag's declared type: return type} over function's overloads."""
        out = {}
        for overload in typing.get_overloads(function):
            hints = typing.get_type_hints(overload)
            out[hints[flag]] = hints["return"]
        return out

    def test_overloads_declare_what_each_flag_returns(self):
        pair_with_paths = typing.Tuple[np.ndarray, typing.List[Path]]
        two_arrays = typing.Tuple[np.ndarray, np.ndarray]
        for function, flag, pair in ((Client.distances, "with_path", pair_with_paths),
                                     (MeshSolver.distances, "with_path", pair_with_paths),
                                     (Client.field, "nearest_source", two_arrays),
                                     (MeshSolver.field, "nearest_source", two_arrays)):
            returns = self.returns_by_flag(function, flag)
            name = function.__qualname__
            self.assertEqual(returns[typing.Literal[False]], np.ndarray, msg=name)
            self.assertEqual(returns[typing.Literal[True]], pair, msg=name)
            self.assertEqual(returns[bool], typing.Union[np.ndarray, pair], msg=name)


if __name__ == "__main__":
    unittest.main(argv=[sys.argv[0], "-v"])
