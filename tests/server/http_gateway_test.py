#!/usr/bin/python3
"""The HTTP/JSON gateway with curl against a real daemon on 127.0.0.1.

Distance, field and matrix answers over HTTP must equal the gRPC answers
bit for bit (JSON numbers are printed round-trip exact); errors carry the
gRPC code and the mapped HTTP status; the bearer token and TLS apply as on
the gRPC listener.

Usage: http_gateway_test.py BUILD_BIN_DIR SOURCE_DIR
"""
import io
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
import unittest
import urllib.error
import urllib.request

import numpy as np

BIN, SRC = sys.argv[1], sys.argv[2]
sys.path.insert(0, os.path.join(SRC, "client", "python"))
from geodesic_client import Client  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import daemon_ports  # noqa: E402
from comparisons import assert_same  # noqa: E402

EPS = 0.01
TOKEN = "s3cret-token"
ORIGIN = "https://app.example"


def start_daemon(work, name, *flags):
    """(process, log, gRPC port, HTTP port) of a daemon logging to {work}/{name}.log."""
    log = open(f"{work}/{name}.log", "w+")
    daemon, ports = daemon_ports.start_daemon(
        BIN, work, ["--graph-dir", f"{work}/graphs-{name}", "--log-level", "warning",
                    "--pseudo-vertex-limit", "0", *flags],
        stderr=log, http=True)
    return daemon, log, ports["grpc"], ports["http"]


def curl(url, method="GET", body=None, token=TOKEN, raw=None, extra=()):
    """(HTTP status, parsed JSON body) of one curl call."""
    cmd = ["curl", "-sS", "--max-time", "60", "-X", method, "-w", "\n%{http_code}", *extra]
    if token is not None:
        cmd += ["-H", f"Authorization: Bearer {token}"]
    data = raw if raw is not None else (json.dumps(body) if body is not None else None)
    if data is not None:
        if not any(str(e).lower().startswith("content-type:") for e in extra):
            cmd += ["-H", "Content-Type: application/json"]
        cmd += ["--data-binary", "@-"]
    out = subprocess.run(cmd + [url], input=data.encode() if data is not None else None,
                         capture_output=True, check=True).stdout.decode()
    text, _, status = out.rpartition("\n")
    return int(status), json.loads(text) if text else None


class Answer:
    def __init__(self, status, headers, body):
        self.status, self.headers, self.body = status, headers, body


def http_request(url, method, headers):
    """One request with urllib: status, headers and body text, errors included."""
    req = urllib.request.Request(url, method=method, headers=headers)
    try:
        with urllib.request.urlopen(req, timeout=60) as r:
            return Answer(r.status, r.headers, r.read().decode())
    except urllib.error.HTTPError as e:
        return Answer(e.code, e.headers, e.read().decode())


def post_bytes(url, body, headers):
    """(HTTP status, headers, body bytes) of a POST of JSON `body` with the token."""
    req = urllib.request.Request(url, method="POST", data=json.dumps(body).encode(), headers={
        "Content-Type": "application/json", "Authorization": f"Bearer {TOKEN}", **headers})
    try:
        with urllib.request.urlopen(req, timeout=60) as r:
            return r.status, r.headers, r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.headers, e.read()


def inf_to_none(values):
    return [None if math.isinf(v) else v for v in values]


class GatewayTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.work = tempfile.mkdtemp()
        with open(f"{cls.work}/token", "w") as f:
            f.write(TOKEN + "\n")
        cls.daemon, cls.log, grpc_port, http_port = start_daemon(
            cls.work, "plain", "--auth-token-file", f"{cls.work}/token", "--max-pairs", "50",
            "--http-cors-origin", ORIGIN,
            # Its queries name epsilons no one asked for, as a page may.
            "--auto-build-any-epsilon")
        cls.base = f"http://127.0.0.1:{http_port}"
        cls.client = Client(f"127.0.0.1:{grpc_port}", timeout=60, token=TOKEN)
        status, graph = curl(f"{cls.base}/v1/meshes/spot/graph", "POST", {"eps": EPS})
        assert status == 200, graph
        deadline = time.time() + 120
        while graph["state"] != "READY" and time.time() < deadline:
            time.sleep(0.1)
            status, graph = curl(f"{cls.base}/v1/meshes/spot/graph?eps={EPS}")
        assert graph["state"] == "READY", graph
        cls.graph = graph

    @classmethod
    def tearDownClass(cls):
        cls.client.close()
        daemon_ports.stop(cls.daemon)
        cls.log.close()
        shutil.rmtree(cls.work)

    def post(self, what, body, **kw):
        return curl(f"{self.base}/v1/meshes/spot/{what}", "POST", body, **kw)

    def assert_error(self, status, body, http_status, code):
        self.assertEqual(status, http_status, body)
        self.assertEqual(body["error"]["code"], code, body)
        self.assertTrue(body["error"]["message"])

    def test_meshes_and_graph_state(self):
        status, body = curl(f"{self.base}/v1/meshes")
        self.assertEqual(status, 200)
        [spot] = [m for m in body["meshes"] if m["name"] == "spot"]
        self.assertEqual((spot["vertices"], spot["faces"]), (2930, 5856))
        # The mesh's diagnostics: `geodesicd info --json`'s report, keys and values (but
        # where and how fast each read the file).
        info = json.loads(subprocess.run(
            [f"{BIN}/geodesicd", "info", f"{SRC}/data/spot.obj", "--json"], check=True,
            capture_output=True, text=True).stdout)
        del info["mesh_bytes"]
        diagnostics = spot["diagnostics"]
        self.assertEqual(sorted(diagnostics), sorted(info))
        for key in set(info) - {"path", "load_seconds"}:
            self.assertEqual(diagnostics[key], info[key], msg=key)
            self.assertIs(type(diagnostics[key]), type(info[key]), msg=key)
        self.assertEqual(self.graph["progress"], 1.0)
        self.assertEqual(self.graph["nodes"], 2930)
        self.assertGreater(self.graph["edges"], 0)
        status, geo = curl(f"{self.base}/v1/meshes/spot/geometry")
        self.assertEqual(status, 200)
        self.assertEqual((len(geo["positions"]), len(geo["faces"])), (3 * 2930, 3 * 5856))

    def graph_when_done(self, query):
        """GET .../graph?QUERY until the graph is no longer queued or building."""
        deadline = time.time() + 120
        while True:
            status, graph = curl(f"{self.base}/v1/meshes/spot/graph?{query}")
            if status != 200 or graph["state"] not in ("QUEUED", "BUILDING", "LOADING"):
                return status, graph
            if time.time() > deadline:
                self.fail(f"graph {query} still {graph['state']} after 120 s")
            time.sleep(0.1)

    def test_pseudo_vertex_graph_over_http_equals_grpc(self):
        # The graph with pseudo vertices is its own graph: requested, watched and
        # queried by pseudo_vertices, never confused with the plain one of the same eps.
        status, graph = self.post("graph", {"eps": EPS, "pseudo_vertices": True})
        self.assertEqual(status, 200, graph)
        self.assertTrue(graph["pseudo_vertices"])
        status, graph = self.graph_when_done(f"eps={EPS}&pseudo_vertices=true")
        self.assertEqual((status, graph["state"]), (200, "READY"), graph)
        self.assertTrue(graph["pseudo_vertices"])
        self.assertGreater(graph["nodes"], 2930)
        status, plain = curl(f"{self.base}/v1/meshes/spot/graph?eps={EPS}&pseudo_vertices=false")
        self.assertEqual((status, plain["nodes"], plain["pseudo_vertices"]), (200, 2930, False))
        status, body = curl(f"{self.base}/v1/meshes/spot/graph?eps={EPS}&pseudo_vertices=yes")
        self.assert_error(status, body, 400, "INVALID_ARGUMENT")
        self.assertIn("pseudo_vertices=yes", body["error"]["message"])

        pairs = [["v:0", "v:1500"], ["f:0:0.2,0.3,0.5", "e:10:0.25"]]
        a, b = [p for p, _ in pairs], [q for _, q in pairs]
        status, body = self.post("distance", {"pairs": pairs, "eps": EPS, "pseudo_vertices": True})
        self.assertEqual(status, 200, body)
        self.assertTrue(body["pseudo_vertices"])
        expected = self.client.distances("spot", a, b, epsilon=EPS, pseudo_vertices=True)
        self.assertTrue(all(isinstance(d, float) and d > 0 for d in body["distances"]), body)
        self.assertEqual(body["distances"], list(expected))
        status, plain = self.post("distance", {"pairs": pairs, "eps": EPS})
        self.assertFalse(plain["pseudo_vertices"])
        self.assertEqual(plain["distances"], list(self.client.distances("spot", a, b, epsilon=EPS)))

        status, body = self.post("field", {"sources": ["v:3"], "eps": EPS, "pseudo_vertices": True})
        self.assertEqual(status, 200, body)
        self.assertTrue(body["pseudo_vertices"])
        # spot is one piece: every distance is a number, on both sides.
        self.assertTrue(body["distances"] and all(isinstance(d, float) for d in body["distances"]))
        self.assertEqual(body["distances"], inf_to_none(
            self.client.field("spot", ["v:3"], epsilon=EPS, pseudo_vertices=True)))
        status, body = self.post("matrix", {"sources": a, "targets": b, "eps": EPS,
                                            "pseudo_vertices": True})
        self.assertEqual(status, 200, body)
        self.assertTrue(body["pseudo_vertices"])
        self.assertEqual(body["distances"], self.client.matrix(
            "spot", a, b, epsilon=EPS, pseudo_vertices=True).tolist())

    def test_sample_equals_grpc(self):
        status, body = self.post("sample", {"count": 5, "seed": 3, "eps": EPS})
        self.assertEqual(status, 200, body)
        vertices, radius = self.client.sample_points("spot", 5, seed=3, epsilon=EPS)
        self.assertEqual(body["vertices"], vertices.tolist())
        self.assertEqual(body["covering_radius"], radius)
        self.assertEqual((body["eps"], body["pseudo_vertices"]), (EPS, False))
        status, body = self.post("sample", {"count": 0, "eps": EPS})
        self.assert_error(status, body, 400, "INVALID_ARGUMENT")
        status, body = self.post("sample", {"seed": 1, "eps": EPS})
        self.assert_error(status, body, 400, "INVALID_ARGUMENT")
        self.assertIn('"count"', body["error"]["message"])
        status, body = self.post("sample", {"count": 2, "seed": -1, "eps": EPS})
        self.assert_error(status, body, 400, "INVALID_ARGUMENT")

    def test_distance_equals_grpc(self):
        pairs = [["v:0", "v:1500"], ["f:0:0.2,0.3,0.5", "e:10:0.25"], ["v:7", "v:7"]]
        status, body = self.post("distance", {"pairs": pairs, "eps": EPS, "path": False})
        self.assertEqual(status, 200, body)
        expected = list(self.client.distances("spot", [a for a, _ in pairs], [b for _, b in pairs],
                                              epsilon=EPS))
        self.assertEqual(body["distances"], expected)
        self.assertEqual(body["distances"][2], 0)
        self.assertNotIn("paths", body)

        status, body = self.post("distance", {"pairs": pairs[:1], "eps": EPS, "path": True})
        self.assertEqual(status, 200, body)
        distances, [path] = self.client.distances("spot", [pairs[0][0]], [pairs[0][1]], epsilon=EPS,
                                                  with_path=True)
        self.assertEqual(body["distances"], list(distances))
        self.assertEqual(body["paths"][0], path.xyz.tolist())

        # xyz specs are snapped as the Snap RPC snaps them.
        [snapped] = self.client.snap("spot", [(0.1, 0.2, 0.3)])
        status, body = self.post("distance", {"pairs": [["xyz:0.1,0.2,0.3", "v:9"]], "eps": EPS})
        self.assertEqual(status, 200, body)
        self.assertEqual(body["distances"], [self.client.distance("spot", snapped, "v:9", EPS)])

    def test_snap_equals_grpc_and_says_how_far_each_position_was(self):
        status, geo = curl(f"{self.base}/v1/meshes/spot/geometry")
        self.assertEqual(status, 200)
        on_surface = geo["positions"][27:30]  # vertex 9
        lifted = [on_surface[0], on_surface[1], on_surface[2] + 0.25]
        status, body = self.post("snap", {"positions": [on_surface, lifted]})
        self.assertEqual(status, 200, body)
        self.assertEqual(len(body["points"]), 2)
        # Both print round-trip exact numbers, C++ with 17 digits, Python the shortest.
        def parsed(spec):
            kind, element, *rest = spec.split(":")
            return kind, int(element), [float(x) for x in rest[0].split(",")] if rest else []
        self.assertEqual([parsed(p) for p in body["points"]],
                         [parsed(p) for p in self.client.snap("spot", [on_surface, lifted])])
        near, far = body["distances"]
        self.assertLessEqual(near, 1e-12)
        # Vertex 9 is 0.25 from the lifted position, so the nearest point is no farther.
        self.assertGreater(far, 0)
        self.assertLessEqual(far, 0.25 * (1 + 1e-12))

    def test_field_equals_grpc_with_null_where_unreachable(self):
        sources = ["v:3", "f:100:0.1,0.1,0.8"]
        status, body = self.post("field", {"sources": sources, "eps": EPS})
        self.assertEqual(status, 200, body)
        expected = self.client.field("spot", sources, epsilon=EPS)
        self.assertEqual(body["distances"], expected.tolist())
        # Beyond max_distance vertices are +inf over gRPC, null over HTTP.
        status, body = self.post("field", {"sources": ["v:3"], "eps": EPS, "max_distance": 0.3})
        self.assertEqual(status, 200, body)
        expected = self.client.field("spot", ["v:3"], epsilon=EPS, max_distance=0.3)
        self.assertTrue(any(math.isinf(v) for v in expected))
        self.assertEqual(body["distances"], inf_to_none(expected.tolist()))

    def test_matrix_equals_grpc(self):
        sources, targets = ["v:0", "v:10"], ["v:100", "v:200", "f:5:0.3,0.3,0.4"]
        status, body = self.post("matrix", {"sources": sources, "targets": targets, "eps": EPS})
        self.assertEqual(status, 200, body)
        self.assertEqual(body["distances"],
                         self.client.matrix("spot", sources, targets, epsilon=EPS).tolist())

    def test_matrix_as_npy_equals_the_json_answer(self):
        sources = ["v:0", "v:10", "f:0:0.2,0.3,0.5"]
        targets = ["v:100", "v:200", "f:5:0.3,0.3,0.4", "v:0"]
        body = {"sources": sources, "targets": targets, "eps": EPS}
        status, as_json = self.post("matrix", body)
        self.assertEqual(status, 200, as_json)
        want = np.array(as_json["distances"], dtype=np.float64)
        self.assertEqual(want.shape, (3, 4))
        self.assertTrue(np.isfinite(want).all())
        self.assertEqual(want[0, 3], 0)
        url = f"{self.base}/v1/meshes/spot/matrix"
        for dtype, descr in ((None, "<f8"), ("float64", "<f8"), ("float32", "<f4")):
            request = dict(body, **({"dtype": dtype} if dtype else {}))
            status, headers, data = post_bytes(url, request, {"Accept": "application/x-npy"})
            self.assertEqual(status, 200, data[:200])
            self.assertEqual(headers["Content-Type"], "application/x-npy")
            self.assertEqual(data[:8], b"\x93NUMPY\x01\x00")
            header_len = int.from_bytes(data[8:10], "little")
            self.assertEqual((10 + header_len) % 64, 0)
            self.assertEqual(data[10 + header_len - 1:10 + header_len], b"\n")
            got = np.load(io.BytesIO(data))
            self.assertEqual((got.dtype, got.shape), (np.dtype(descr), (3, 4)), dtype)
            self.assertEqual(got.tobytes(), want.astype(descr).tobytes(), dtype)
        # JSON too can carry float32 values: the float64 ones rounded.
        status, narrow = self.post("matrix", dict(body, dtype="float32"))
        self.assertEqual(status, 200, narrow)
        self.assertEqual(narrow["dtype"], "float32")
        self.assertEqual(np.array(narrow["distances"], dtype=np.float32).tobytes(),
                         want.astype(np.float32).tobytes())
        status, bad = self.post("matrix", dict(body, dtype="float16"))
        self.assert_error(status, bad, 400, "INVALID_ARGUMENT")
        self.assertIn('"float16"', bad["error"]["message"])
        status, headers, data = post_bytes(url, dict(body, dtype=3),
                                           {"Accept": "application/x-npy"})
        self.assertEqual(status, 400)
        self.assertEqual(headers["Content-Type"], "application/json")
        self.assertEqual(json.loads(data)["error"]["code"], "INVALID_ARGUMENT")

    def test_exact_distance_and_matrix_equal_grpc(self):
        pairs = [["v:0", "v:1500"], ["f:0:0.2,0.3,0.5", "e:10:0.25"]]
        status, body = self.post("distance", {"pairs": pairs, "eps": EPS, "exact": True})
        self.assertEqual(status, 200, body)
        self.assertIs(body["exact"], True)
        self.assertEqual(body["method"], "exact")
        expected = self.client.distances("spot", [a for a, _ in pairs], [b for _, b in pairs],
                                         epsilon=EPS, exact=True)
        assert_same(body["distances"], expected)
        graph_only = self.client.distances("spot", [a for a, _ in pairs], [b for _, b in pairs],
                                           epsilon=EPS)
        self.assertTrue(all(e <= g * (1 + 1e-12) for e, g in zip(expected, graph_only)))
        sources, targets = ["v:0"], ["v:100", "f:5:0.3,0.3,0.4"]
        status, body = self.post("matrix", {"sources": sources, "targets": targets, "eps": EPS,
                                            "exact": True})
        self.assertEqual(status, 200, body)
        self.assertIs(body["exact"], True)
        assert_same(body["distances"],
                    self.client.matrix("spot", sources, targets, epsilon=EPS, exact=True))
        status, body = self.post("distance", {"pairs": pairs, "eps": EPS, "exact": "yes"})
        self.assertEqual(status, 400, body)
        self.assertIn('"exact"', body["error"]["message"])

    def test_errors_map_grpc_codes(self):
        status, body = curl(f"{self.base}/v1/meshes/nope/distance", "POST",
                            {"pairs": [["v:0", "v:1"]], "eps": EPS})
        self.assert_error(status, body, 404, "NOT_FOUND")
        status, body = self.post("distance", {"pairs": [["v:0", "q:1"]], "eps": EPS})
        self.assert_error(status, body, 400, "INVALID_ARGUMENT")
        self.assertIn("pair end 1", body["error"]["message"])
        status, body = self.post("field", {"sources": ["v:99999"], "eps": EPS})
        self.assert_error(status, body, 400, "OUT_OF_RANGE")
        status, body = self.post("field", {"sources": ["v:1"], "eps": 0.9})
        self.assert_error(status, body, 400, "INVALID_ARGUMENT")
        # No graph was requested at this epsilon: the query starts it and waits.
        status, body = self.post("field", {"sources": ["v:1"], "eps": 0.2})
        self.assertEqual(status, 200, body)
        self.assertEqual(len(body["distances"]), 2930)
        self.assertEqual(body["eps"], 0.2)
        status, body = self.post("distance", {"pairs": [["v:0", "v:1"]] * 51, "eps": EPS})
        self.assert_error(status, body, 429, "RESOURCE_EXHAUSTED")
        status, body = self.post("matrix", None, raw="{not json")
        self.assert_error(status, body, 400, "INVALID_ARGUMENT")
        status, body = self.post("matrix", None, raw=json.dumps({"sources": [[1]] * 4_000_000}))
        self.assert_error(status, body, 413, "RESOURCE_EXHAUSTED")
        status, body = curl(f"{self.base}/v1/meshes/spot/field?timeout=0.000001", "POST",
                            {"sources": ["v:1"], "eps": EPS})
        self.assert_error(status, body, 504, "DEADLINE_EXCEEDED")
        status, body = curl(f"{self.base}/v1/meshes/spot/field?timeout=soon", "POST",
                            {"sources": ["v:1"], "eps": EPS})
        self.assert_error(status, body, 400, "INVALID_ARGUMENT")
        status, body = curl(f"{self.base}/v1/meshes/spot/field?timeout=30", "POST",
                            {"sources": ["v:1"], "eps": EPS})
        self.assertEqual(status, 200, body)
        status, body = curl(f"{self.base}/v1/no/such/route")
        self.assert_error(status, body, 404, "NOT_FOUND")

    def test_hostile_requests_get_errors_and_the_server_keeps_serving(self):
        # Bytes that are not UTF-8 in the path, quoted by the 404's message.
        status, body = curl(f"{self.base}/v1/nosuch%FF")
        self.assert_error(status, body, 404, "NOT_FOUND")
        status, body = curl(f"{self.base}/v1/meshes/%FF/graph?eps={EPS}")
        self.assertEqual(status // 100, 4, body)
        # 100,000 nested arrays: refused by depth, not by a stack overflow.
        deep = '{"positions": [' + "[" * 100_000 + "]" * 100_000 + "]}"
        status, body = self.post("snap", None, raw=deep)
        self.assert_error(status, body, 400, "INVALID_ARGUMENT")
        self.assertIn("64 levels", body["error"]["message"])
        # A huge offending value is quoted, not echoed whole.
        status, body = self.post("snap", {"positions": [["x" * 100_000]]})
        self.assert_error(status, body, 400, "INVALID_ARGUMENT")
        self.assertLess(len(body["error"]["message"]), 300)
        status, body = self.post("field", {"sources": ["v:1"], "eps": EPS, "epsilon": 0.02})
        self.assert_error(status, body, 400, "INVALID_ARGUMENT")
        self.assertIn("disagree", body["error"]["message"])
        # curl -d's form content type is capped by the HTTP library: say so.
        status, body = curl(f"{self.base}/v1/meshes/spot/field", "POST", token=TOKEN,
                            extra=["--data-binary", json.dumps(
                                {"sources": ["v:1"] * 2000, "eps": EPS})])
        self.assert_error(status, body, 413, "RESOURCE_EXHAUSTED")
        self.assertIn("Content-Type: application/json", body["error"]["message"])
        status, body = self.post("field", {"sources": ["v:1"], "eps": EPS})
        self.assertEqual(status, 200, body)

    def test_bodies_are_strict_and_methods_named(self):
        # A typo is refused, naming the key and the keys the call takes.
        status, body = curl(f"{self.base}/v1/meshes/spot/graph", "POST",
                            {"eps": EPS, "pseudo_vertex": True})
        self.assert_error(status, body, 400, "INVALID_ARGUMENT")
        self.assertIn('"pseudo_vertex"', body["error"]["message"])
        self.assertIn("pseudo_vertices", body["error"]["message"])
        status, body = self.post("distance", {"pairs": [["v:0", "v:1"]], "eps": EPS, "paths": 1})
        self.assert_error(status, body, 400, "INVALID_ARGUMENT")
        self.assertIn('"paths"', body["error"]["message"])
        # A known path with another method: 405 and the methods it takes.
        r = http_request(f"{self.base}/v1/meshes/spot/distance", "GET",
                         {"Authorization": f"Bearer {TOKEN}"})
        self.assertEqual(r.status, 405, r.body)
        self.assertEqual(r.headers.get("Allow"), "POST")

    def test_meshes_are_registered_and_unloaded_over_http(self):
        # A file under the mesh root, by path.
        status, body = curl(f"{self.base}/v1/meshes", "POST", {"name": "by-path",
                                                                "path": "spot.obj"})
        self.assertEqual(status, 200, body)
        self.assertEqual((body["name"], body["vertices"]), ("by-path", 2930))
        # The file's own bytes.
        with open(os.path.join(SRC, "data", "spot.obj"), "rb") as f:
            spot = f.read()
        status, body = curl(f"{self.base}/v1/meshes?name=by-bytes&format=obj", "POST",
                            raw=spot.decode(), extra=["-H", "Content-Type: application/octet-stream"])
        self.assertEqual(status, 200, body)
        self.assertEqual(body["vertices"], 2930)
        # Arrays: a tetrahedron, read back equal.
        vertices = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]
        faces = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]
        status, body = curl(f"{self.base}/v1/meshes", "POST",
                            {"name": "tet", "vertices": vertices, "faces": faces})
        self.assertEqual(status, 200, body)
        self.assertEqual((body["vertices"], body["faces"]), (4, 4))
        status, geometry = curl(f"{self.base}/v1/meshes/tet/geometry")
        self.assertEqual(status, 200, geometry)
        self.assertEqual(geometry["positions"], [c for v in vertices for c in v])
        self.assertEqual(geometry["faces"], [i for f in faces for i in f])
        # The first query on it just works (its graph is started and waited for).
        status, body = self.post_to("tet", "distance", {"pairs": [["v:0", "v:3"]], "eps": 0.05})
        self.assertEqual(status, 200, body)
        self.assertAlmostEqual(body["distances"][0], 1.0, delta=0.05)
        # Bad bodies name the problem.
        status, body = curl(f"{self.base}/v1/meshes", "POST", {"name": "x", "pth": "spot.obj"})
        self.assert_error(status, body, 400, "INVALID_ARGUMENT")
        self.assertIn('"pth"', body["error"]["message"])
        status, body = curl(f"{self.base}/v1/meshes", "POST", {"name": "x", "path": 5})
        self.assert_error(status, body, 400, "INVALID_ARGUMENT")
        self.assertIn("path", body["error"]["message"])
        status, body = curl(f"{self.base}/v1/meshes", "POST",
                            {"name": "x", "vertices": [[0, 0]], "faces": [[0, 1, 2]]})
        self.assert_error(status, body, 400, "INVALID_ARGUMENT")
        status, body = curl(f"{self.base}/v1/meshes", "POST", raw="v 0 0 0\n",
                            extra=["-H", "Content-Type: application/octet-stream"])
        self.assert_error(status, body, 400, "INVALID_ARGUMENT")
        self.assertIn("?name=", body["error"]["message"])
        # Unloaded, they are gone.
        for name in ("by-path", "by-bytes", "tet"):
            status, body = curl(f"{self.base}/v1/meshes/{name}", "DELETE")
            self.assertEqual(status, 200, body)
            status, body = curl(f"{self.base}/v1/meshes/{name}")
            self.assert_error(status, body, 404, "NOT_FOUND")

    def test_regions_are_registered_over_http(self):
        status, geo = curl(f"{self.base}/v1/meshes/spot/geometry")
        self.assertEqual(status, 200, geo)
        upper = [v for v in range(len(geo["positions"]) // 3) if geo["positions"][3 * v + 1] > 0]
        self.assertTrue(0 < len(upper) < 2930, len(upper))
        # A by-path copy of spot as the parent, so that spot can go on
        # being unloaded and registered by other tests.
        status, body = curl(f"{self.base}/v1/meshes", "POST", {"name": "parent",
                                                                "path": "spot.obj"})
        self.assertEqual(status, 200, body)
        status, region = curl(f"{self.base}/v1/meshes/parent/regions", "POST",
                              {"name": "upper", "vertex_ids": upper})
        self.assertEqual(status, 200, region)
        self.assertEqual((region["parent"], region["parent_vertices"], region["parent_faces"]),
                         ("parent", 2930, 5856))
        self.assertTrue(0 < region["vertices"] <= len(upper), region["vertices"])
        status, listed = curl(f"{self.base}/v1/meshes")
        self.assertEqual(status, 200, listed)
        [whole] = [m for m in listed["meshes"] if m["name"] == "parent"]
        self.assertNotIn("parent", whole)
        # Queried as any mesh, in its own ids.
        last = region["vertices"] - 1
        status, body = self.post_to("upper", "distance", {"pairs": [["v:0", f"v:{last}"]],
                                                          "eps": EPS})
        self.assertEqual(status, 200, body)
        self.assertGreater(body["distances"][0], 0)
        status, body = self.post_to("upper", "distance", {"pairs": [["v:0", f"v:{last + 1}"]],
                                                          "eps": EPS})
        self.assert_error(status, body, 400, "OUT_OF_RANGE")
        # Its parent stays while it is registered; mistakes are named.
        status, body = curl(f"{self.base}/v1/meshes/parent", "DELETE")
        self.assert_error(status, body, 409, "FAILED_PRECONDITION")
        self.assertIn("'upper'", body["error"]["message"])
        status, body = curl(f"{self.base}/v1/meshes/parent/regions", "POST",
                            {"name": "x", "vertex_ids": [0, 1, 2], "face_ids": [0]})
        self.assert_error(status, body, 400, "INVALID_ARGUMENT")
        status, body = curl(f"{self.base}/v1/meshes/parent/regions", "POST",
                            {"name": "x", "vertex_ids": [0, 99999]})
        self.assert_error(status, body, 400, "OUT_OF_RANGE")
        self.assertIn("99999", body["error"]["message"])
        status, body = curl(f"{self.base}/v1/meshes/parent/regions", "POST",
                            {"name": "x", "vertex_idz": [0]})
        self.assert_error(status, body, 400, "INVALID_ARGUMENT")
        status, body = curl(f"{self.base}/v1/meshes/nosuch/regions", "POST",
                            {"name": "x", "vertex_ids": upper})
        self.assert_error(status, body, 404, "NOT_FOUND")
        for name in ("upper", "parent"):
            status, body = curl(f"{self.base}/v1/meshes/{name}", "DELETE")
            self.assertEqual(status, 200, body)

    def post_to(self, mesh, what, body):
        return curl(f"{self.base}/v1/meshes/{mesh}/{what}", "POST", body)

    def test_cors_for_the_configured_origin(self):
        # A preflight needs no token and names the path's methods.
        r = http_request(f"{self.base}/v1/meshes/spot/graph", "OPTIONS",
                         {"Origin": ORIGIN, "Access-Control-Request-Method": "POST"})
        self.assertEqual(r.status, 204, r.body)
        self.assertEqual(r.headers.get("Access-Control-Allow-Origin"), ORIGIN)
        methods = {m.strip() for m in r.headers.get("Access-Control-Allow-Methods", "").split(",")}
        self.assertTrue({"GET", "POST", "DELETE"} <= methods, methods)
        self.assertIn("Authorization", r.headers.get("Access-Control-Allow-Headers", ""))
        # Answers, errors included, carry the origin for the page to read them.
        r = http_request(f"{self.base}/v1/meshes", "GET",
                         {"Origin": ORIGIN, "Authorization": f"Bearer {TOKEN}"})
        self.assertEqual(r.status, 200, r.body)
        self.assertEqual(r.headers.get("Access-Control-Allow-Origin"), ORIGIN)
        r = http_request(f"{self.base}/v1/meshes", "GET", {"Origin": ORIGIN})
        self.assertEqual(r.status, 401, r.body)
        self.assertEqual(r.headers.get("Access-Control-Allow-Origin"), ORIGIN)

    def test_bearer_token_is_required(self):
        for token in (None, "wrong"):
            status, body = curl(f"{self.base}/v1/meshes", token=token)
            self.assert_error(status, body, 401, "UNAUTHENTICATED")
            status, body = self.post("distance", {"pairs": [["v:0", "v:1"]]}, token=token)
            self.assert_error(status, body, 401, "UNAUTHENTICATED")
            status, body = curl(f"{self.base}/v1/meshes/spot/geometry", token=token)
            self.assert_error(status, body, 401, "UNAUTHENTICATED")

    def test_openapi_and_viewer_are_served(self):
        status, spec = curl(f"{self.base}/v1/openapi.json", token=None)
        self.assertEqual(status, 200)
        self.assertTrue(spec["openapi"].startswith("3."))
        for path in ["/v1/meshes", "/v1/meshes/{name}/graph", "/v1/meshes/{name}/distance",
                     "/v1/meshes/{name}/field", "/v1/meshes/{name}/matrix",
                     "/v1/meshes/{name}/snap", "/v1/meshes/{name}/sample"]:
            self.assertIn(path, spec["paths"])
        self.assertIn("post", spec["paths"]["/v1/meshes"])
        self.assertIn("delete", spec["paths"]["/v1/meshes/{name}"])
        page = subprocess.run(["curl", "-sS", f"{self.base}/"], capture_output=True,
                              check=True).stdout.decode()
        self.assertIn('id="distance"', page)
        head = subprocess.run(["curl", "-sSI", f"{self.base}/three/build/three.module.js"],
                              capture_output=True, check=True).stdout.decode()
        self.assertIn("200 OK", head)
        self.assertIn("text/javascript", head)

    def test_tls_uses_the_grpc_certificate(self):
        work = self.work
        quiet = dict(check=True, capture_output=True)
        subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1",
                        "-subj", "/CN=127.0.0.1", "-addext", "subjectAltName=IP:127.0.0.1",
                        "-keyout", f"{work}/server.key", "-out", f"{work}/server.crt"], **quiet)
        daemon, log, _, port = start_daemon(work, "tls", "--tls-cert", f"{work}/server.crt",
                                            "--tls-key", f"{work}/server.key")
        try:
            status, body = curl(f"https://127.0.0.1:{port}/v1/meshes", token=None,
                                extra=("--cacert", f"{work}/server.crt"))
            self.assertEqual(status, 200, body)
            self.assertIn("spot", [m["name"] for m in body["meshes"]])
            plain = subprocess.run(["curl", "-sS", "--max-time", "10",
                                    f"http://127.0.0.1:{port}/v1/meshes"], capture_output=True)
            self.assertNotEqual(plain.returncode, 0)
        finally:
            daemon_ports.stop(daemon)
            log.close()

    def test_mutual_tls_uses_the_grpc_client_ca(self):
        work = f"{self.work}/mtls"
        os.mkdir(work)

        def openssl(*args):
            subprocess.run(["openssl", *args], cwd=work, check=True, capture_output=True)

        openssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1", "-subj",
                "/CN=test-ca", "-keyout", "ca.key", "-out", "ca.crt")
        with open(f"{work}/san.ext", "w") as f:
            f.write("subjectAltName=IP:127.0.0.1\n")
        for name in ("server", "client"):
            openssl("req", "-newkey", "rsa:2048", "-nodes", "-subj", f"/CN={name}", "-keyout",
                    f"{name}.key", "-out", f"{name}.csr")
            openssl("x509", "-req", "-in", f"{name}.csr", "-CA", "ca.crt", "-CAkey", "ca.key",
                    "-CAcreateserial", "-days", "1", "-extfile", "san.ext", "-out", f"{name}.crt")
        daemon, log, _, port = start_daemon(
            self.work, "mtls", "--tls-cert", f"{work}/server.crt", "--tls-key",
            f"{work}/server.key", "--tls-client-ca", f"{work}/ca.crt")
        url = f"https://127.0.0.1:{port}/v1/meshes"
        try:
            status, body = curl(url, token=None, extra=("--cacert", f"{work}/ca.crt", "--cert",
                                                        f"{work}/client.crt", "--key",
                                                        f"{work}/client.key"))
            self.assertEqual(status, 200, body)
            anonymous = subprocess.run(["curl", "-sS", "--max-time", "10", "--cacert",
                                        f"{work}/ca.crt", url], capture_output=True)
            self.assertNotEqual(anonymous.returncode, 0, anonymous.stdout)
        finally:
            daemon_ports.stop(daemon)
            log.close()


if __name__ == "__main__":
    unittest.main(argv=sys.argv[:1], verbosity=2)
