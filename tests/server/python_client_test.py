#!/usr/bin/python3
"""Tests of the Python client against a real daemon on 127.0.0.1.

Usage: python_client_test.py BUILD_BIN_DIR SOURCE_DIR
"""
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import unittest

import numpy as np

BIN, SRC = sys.argv[1], sys.argv[2]
sys.path.insert(0, os.path.join(SRC, "client", "python"))
import grpc  # noqa: E402
from geodesic_client import Client  # noqa: E402


def free_port():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


class ClientTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.work = tempfile.mkdtemp()
        cls.port = free_port()
        cls.daemon = subprocess.Popen(
            [f"{BIN}/geodesicd", "serve", "--listen", f"127.0.0.1:{cls.port}", "--graph-dir",
             f"{cls.work}/graphs", "--mesh-root", f"{SRC}/data", "--log-level", "warning"],
            stderr=subprocess.DEVNULL)
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

    def graph_file(self):
        return [f for f in os.listdir(f"{self.work}/graphs") if "eps0.01" in f][0]

    def test_field_is_a_numpy_array_equal_to_the_offline_field(self):
        field = self.client.field("spot", ["v:3"], epsilon=0.01)
        self.assertEqual(field.shape, (2930,))
        self.assertEqual(field[3], 0)
        out = f"{self.work}/offline.f64"
        subprocess.run([f"{BIN}/geodesicd", "field", "--mesh", f"{SRC}/data/spot.obj", "--graph",
                        f"{self.work}/graphs/{self.graph_file()}", "--source", "v:3", "--out", out],
                       check=True, capture_output=True)
        np.testing.assert_array_equal(field, np.fromfile(out))

    def test_distance_path_and_matrix_agree(self):
        d = self.client.distance("spot", "f:0:0.2,0.3,0.5", "v:1500", epsilon=0.01)
        path = self.client.path("spot", "f:0:0.2,0.3,0.5", "v:1500", epsilon=0.01)
        self.assertGreater(d, 0)
        self.assertLessEqual(path.length, d * (1 + 1e-6))
        self.assertEqual(path.points[-1], "v:1500")
        self.assertEqual(path.xyz.shape, (len(path.points), 3))
        # The matrix comes from label-correcting fields, the pair from bidirectional search on
        # the augmented graph: different searches, so both are checked against the exact
        # distance (never below it, at most 1+eps above it) rather than against each other.
        m = self.client.matrix("spot", ["v:0", "v:10"], ["v:100", "v:200", "v:300"], epsilon=0.01)
        self.assertEqual(m.shape, (2, 3))
        exact = f"{self.work}/exact0.f64"
        subprocess.run([f"{BIN}/geodesicd", "exact", "--mesh", f"{SRC}/data/spot.obj", "--source",
                        "v:0", "--out", exact], check=True, capture_output=True)
        truth = np.fromfile(exact)
        pair = self.client.distance("spot", "v:0", "v:200", epsilon=0.01)
        for got, target in ((m[0, 0], 100), (m[0, 1], 200), (m[0, 2], 300), (pair, 200)):
            self.assertGreaterEqual(got, truth[target] * (1 - 1e-9))
            self.assertLessEqual(got, truth[target] * 1.01)

    def test_snap_and_positions(self):
        (snapped,) = self.client.snap("spot", [(0.1, 0.2, 0.3)])
        self.assertTrue(snapped.startswith(("f:", "e:", "v:")))
        d = self.client.distance("spot", "xyz:0.1,0.2,0.3", snapped, epsilon=0.01)
        self.assertAlmostEqual(d, 0.0, places=9)

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
