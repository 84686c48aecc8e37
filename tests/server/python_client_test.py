#!/usr/bin/python3
"""Tests of the Python client against a real daemon on 127.0.0.1.

Usage: python_client_test.py BUILD_BIN_DIR SOURCE_DIR
"""
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import unittest

import numpy as np

BIN, SRC = sys.argv[1], sys.argv[2]
sys.path.insert(0, os.path.join(SRC, "client", "python"))
import grpc  # noqa: E402
from geodesic_client import Client, GraphState  # noqa: E402
from daemon_ports import start_daemon  # noqa: E402


class ClientTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.work = tempfile.mkdtemp()
        cls.daemon, ports = start_daemon(
            BIN, cls.work, ["--graph-dir", f"{cls.work}/graphs", "--mesh-root", f"{SRC}/data",
                            "--log-level", "warning"])
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
        cls.daemon.terminate()
        cls.daemon.wait(timeout=30)
        shutil.rmtree(cls.work)

    def graph_file(self, pseudo_vertices=False):
        return [f for f in os.listdir(f"{self.work}/graphs")
                if "eps0.01-" in f and ("-pseudo" in f) == pseudo_vertices][0]

    def test_field_is_a_numpy_array_equal_to_the_offline_field(self):
        field = self.client.field("spot", ["v:3"], epsilon=0.01)
        self.assertEqual(field.shape, (2930,))
        self.assertEqual(field[3], 0)
        out = f"{self.work}/offline.f64"
        subprocess.run([f"{BIN}/geodesicd", "field", "--mesh", f"{SRC}/data/spot.obj", "--graph",
                        f"{self.work}/graphs/{self.graph_file()}", "--source", "v:3", "--out", out],
                       check=True, capture_output=True)
        np.testing.assert_array_equal(field, np.fromfile(out))

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
        np.testing.assert_array_equal(field, np.fromfile(out))
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

    def test_sample_points_cover_the_mesh(self):
        vertices, radius = self.client.sample_points("spot", 8, seed=5, epsilon=0.01)
        self.assertEqual((vertices.dtype, vertices.shape), (np.uint32, (8,)))
        self.assertEqual(len(set(vertices.tolist())), 8)
        again, _ = self.client.sample_points("spot", 8, seed=5, epsilon=0.01)
        np.testing.assert_array_equal(vertices, again)
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
        np.testing.assert_array_equal(got, want)

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
                np.testing.assert_array_equal(got, want)
                sources = list(range(0, 2930, 293))  # 10
                # The minimum of three partial fields: equal up to an ulp where
                # two sources tie.
                np.testing.assert_allclose(tight.field("spot", sources, epsilon=0.01),
                                           self.client.field("spot", sources, epsilon=0.01),
                                           rtol=1e-14)
                positions = np.random.default_rng(5).normal(size=(200, 3)) * 0.5
                self.assertEqual(tight.snap("spot", positions), self.client.snap("spot", positions))
                self.assertEqual((tight.max_pairs, tight.max_sources), (50, 4))
        finally:
            daemon.terminate()
            daemon.wait(timeout=30)
            shutil.rmtree(work)

    def test_one_position_is_one_source_and_a_missing_upload_names_the_file(self):
        one = self.client.field("spot", np.array([0.1, 0.2, 0.3]), epsilon=0.01)
        np.testing.assert_array_equal(
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
        self.assertEqual(m.diagnostics.vertices, 2930)
        self.assertIn("copy", [x.name for x in self.client.meshes()])


if __name__ == "__main__":
    unittest.main(argv=[sys.argv[0], "-v"])
