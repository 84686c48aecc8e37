#!/usr/bin/python3
"""The pip-installable client: installed offline into a fresh venv from a copy of the
sources (as a clean clone has them), then checked against a real daemon and the CLI.

Usage: python_package_test.py BUILD_BIN_DIR SOURCE_DIR
(re-runs itself inside the venv with --inside VENV_WORK_DIR)
"""
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import unittest
from concurrent import futures

import numpy as np

# The script's own directory: imported before the venv run drops the clone
# from sys.path.
import daemon_ports
from comparisons import assert_close, assert_same

BIN, SRC = os.path.abspath(sys.argv[1]), os.path.abspath(sys.argv[2])
EPS = 0.01
N_PAIRS = 10000
# The daemon's limit on pairs per call, below N_PAIRS: the client must split.
MAX_PAIRS = 4000


def install(work):
    """Copies client/python and proto/ (nothing generated) and pip-installs them offline."""
    src = os.path.join(work, "clone")
    shutil.copytree(os.path.join(SRC, "client", "python"), os.path.join(src, "client", "python"),
                    ignore=shutil.ignore_patterns("_proto", "_gen", "build", "dist", "*.egg-info",
                                                  "__pycache__"))
    shutil.copytree(os.path.join(SRC, "proto"), os.path.join(src, "proto"))
    venv = os.path.join(work, "venv")
    subprocess.run(["/usr/bin/python3", "-m", "venv", "--system-site-packages", venv], check=True)
    pip = [f"{venv}/bin/python", "-m", "pip", "install", "-q", "--no-index",
           "--no-build-isolation", f"{src}/client/python"]
    # Without protoc on PATH the install fails and names the Debian packages.
    no_tools = dict(os.environ, PATH=f"{venv}/bin")
    for var in ("PROTOC", "GRPC_PYTHON_PLUGIN"):
        no_tools.pop(var, None)
    r = subprocess.run(pip, capture_output=True, text=True, env=no_tools)
    if r.returncode == 0 or "protobuf-compiler" not in r.stdout + r.stderr:
        sys.exit(f"FAIL install without protoc: rc {r.returncode}, output:\n{r.stdout}{r.stderr}")
    subprocess.run(pip, check=True)
    # An sdist carries its own copy of the proto: it builds away from the clone.
    subprocess.run([f"{venv}/bin/python", "setup.py", "-q", "sdist", "-d", f"{work}/dist"],
                   cwd=f"{src}/client/python", check=True, capture_output=True)
    (sdist,) = os.listdir(f"{work}/dist")
    subprocess.run(pip[:-1] + ["--no-deps", "--target", f"{work}/from-sdist",
                               f"{work}/dist/{sdist}"], check=True)
    if not os.path.isfile(f"{work}/from-sdist/geodesic_client/_proto/geodesic_pb2_grpc.py"):
        sys.exit("FAIL the sdist installed without its gRPC stubs")
    return venv


def start_daemon(work, *extra):
    """geodesicd serve on 127.0.0.1:0; returns (process, port)."""
    with open(f"{work}/daemon.log", "w") as log:
        try:
            daemon, ports = daemon_ports.start_daemon(
                BIN, work, ["--graph-dir", f"{work}/graphs", "--mesh-root", f"{SRC}/data",
                            "--log-level", "warning", "--default-epsilon", str(EPS), *extra],
                stderr=log)
        except RuntimeError as e:
            sys.exit(f"FAIL {e}")
    return daemon, ports["grpc"]


def cli_distances(port, pairs_lines, work):
    """The CLI's answers for "A B" lines, in calls of at most MAX_PAIRS pairs."""
    out = []
    for start in range(0, len(pairs_lines), MAX_PAIRS):
        path = f"{work}/pairs-{start}.txt"
        with open(path, "w") as f:
            f.write("\n".join(pairs_lines[start:start + MAX_PAIRS]) + "\n")
        r = subprocess.run([f"{BIN}/geodesic", "--server", f"127.0.0.1:{port}", "--mesh", "spot",
                            "--eps", str(EPS), "--json", "distance", "--pairs", path],
                           check=True, capture_output=True, text=True)
        out += [np.inf if x["distance"] is None else x["distance"] for x in json.loads(r.stdout)]
    return np.array(out, dtype=np.float64)


def spot_vertices():
    with open(f"{SRC}/data/spot.obj") as f:
        return np.array([[float(x) for x in line.split()[1:4]] for line in f
                         if line.startswith("v ")])


class PackageTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        import geodesic_client as gc
        cls.gc = gc
        cls.work = WORK
        cls.daemon, cls.port = start_daemon(cls.work, "--max-pairs", str(MAX_PAIRS))
        # The client believes the server's default limit: it must learn the lower one.
        cls.client = gc.Client(f"127.0.0.1:{cls.port}", timeout=120, epsilon=EPS)
        cls.client.request_graph("spot")

    @classmethod
    def tearDownClass(cls):
        cls.client.close()
        daemon_ports.stop(cls.daemon)

    def test_installed_not_from_the_source_tree(self):
        self.assertTrue(self.gc.__file__.startswith(os.path.join(self.work, "venv")),
                        self.gc.__file__)

    def test_version_and_typing_marker_are_installed(self):
        # setuptools read the version from geodesic_client/_version.py, for the
        # wheel and the sdist alike.
        from importlib import metadata
        self.assertRegex(self.gc.__version__, r"^\d+\.\d+\.\d+")
        self.assertEqual(metadata.version("geodesic-client"), self.gc.__version__)
        (sdist,) = os.listdir(os.path.join(self.work, "dist"))
        self.assertIn(f"-{self.gc.__version__}.tar.gz", sdist)
        package = os.path.dirname(self.gc.__file__)
        self.assertTrue(os.path.isfile(os.path.join(package, "py.typed")))
        self.assertTrue(os.path.isfile(os.path.join(package, "_version.py")))

    def test_mesh_solver_and_dataclasses_from_the_installed_package(self):
        m = self.client.mesh("spot")
        self.assertIsInstance(m, self.gc.Mesh)
        self.assertEqual(m.diagnostics.details["vertices"], 2930)
        solver = self.client.mesh_solver("spot")
        self.assertEqual(solver.epsilon, EPS)
        assert_same(solver.distances([1, 2, 3], [2000, 1000, 3]),
                                      self.client.distances("spot", [1, 2, 3], [2000, 1000, 3]))
        seen = []
        self.assertIs(solver.request_graph(progress=seen.append).state, self.gc.GraphState.READY)
        self.assertEqual([g.state for g in seen], [self.gc.GraphState.READY])

    def test_numpy_batch_of_10000_pairs_equals_the_cli(self):
        rng = np.random.default_rng(7)
        a = rng.integers(0, 2930, N_PAIRS)
        faces = rng.integers(0, 5856, N_PAIRS)
        bary = rng.random((N_PAIRS, 3)) + 0.01
        bary /= bary.sum(axis=1, keepdims=True)
        got = self.client.distances("spot", a, self.gc.FacePoints(faces, bary))
        self.assertIsInstance(got, np.ndarray)
        self.assertEqual((got.dtype, got.shape), (np.float64, (N_PAIRS,)))
        self.assertEqual(self.client.max_pairs, MAX_PAIRS)  # learnt from the server's error
        lines = [f"v:{v} f:{f}:{b[0]!r},{b[1]!r},{b[2]!r}"
                 for v, f, b in zip(a.tolist(), faces.tolist(), bary.tolist())]
        want = cli_distances(self.port, lines, self.work)
        # Same server, same graph, same doubles in: equal to the last bit (the CLI prints %.17g).
        assert_same(got, want)
        # The same points as (face_ids, barycentrics) tuple and as spec strings.
        assert_same(
            self.client.distances("spot", (faces[:50], bary[:50]), a[:50]),
            self.client.distances("spot", [ln.split()[1] for ln in lines[:50]],
                                  [f"v:{v}" for v in a[:50].tolist()]))

    def test_positions_are_snapped_like_the_cli(self):
        xyz = spot_vertices()[[10, 200, 2000, 1500]] + 1e-4
        ids = np.array([5, 6, 7, 8])
        got = self.client.distances("spot", xyz, ids)
        want = cli_distances(self.port, [f"xyz:{p[0]!r},{p[1]!r},{p[2]!r} v:{v}"
                                         for p, v in zip(xyz.tolist(), ids.tolist())], self.work)
        assert_same(got, want)
        snapped = self.client.snap("spot", xyz)
        assert_same(self.client.distances("spot", snapped, ids), want)

    def test_paths_are_k_by_3_arrays(self):
        dist, paths = self.client.distances("spot", [1, 2, 3], [2000, 1000, 3], with_path=True)
        self.assertEqual(len(paths), 3)
        for d, p in zip(dist, paths):
            self.assertEqual(p.xyz.ndim, 2)
            self.assertEqual(p.xyz.shape[1], 3)
            self.assertEqual(p.xyz.shape[0], len(p.points))
            self.assertLessEqual(p.length, d * (1 + 1e-6) + 1e-12)
        verts = spot_vertices()
        length, xyz = self.client.path("spot", 1, 2000)
        self.assertGreaterEqual(len(xyz), 2)
        assert_close(xyz[0], verts[1], rtol=0, atol=1e-12)
        assert_close(xyz[-1], verts[2000], rtol=0, atol=1e-12)
        # Straight segments across faces: the polyline is the path.
        polyline = np.linalg.norm(np.diff(xyz, axis=0), axis=1).sum()
        self.assertAlmostEqual(polyline / length, 1.0, delta=1e-9)
        self.assertEqual(paths[2].length, 0.0)

    def test_field_is_an_ndarray_and_sources_split_under_the_limit(self):
        sources = np.array([3, 700, 1400, 2100, 2800])
        whole, labels = self.client.field("spot", sources, nearest_source=True)
        self.assertEqual((whole.dtype, whole.shape), (np.float64, (2930,)))
        self.assertTrue(np.all(whole[sources] == 0))
        split = self.gc.Client(f"127.0.0.1:{self.port}", epsilon=EPS, max_sources=2)
        parts, part_labels = split.field("spot", sources, nearest_source=True)
        assert_close(parts, whole, rtol=1e-12, atol=0)
        agree = np.isclose(parts, whole, rtol=1e-12, atol=0) & (labels == part_labels)
        self.assertGreater(agree.mean(), 0.99)  # ties may pick either source
        assert_same(self.client.field("spot", 3, targets=[3, 10]),
                                      self.client.field("spot", [3])[[3, 10]])
        m = split.matrix("spot", sources, np.arange(0, 2930, 7))
        self.assertEqual(m.shape, (5, len(range(0, 2930, 7))))
        assert_same(m, self.client.matrix("spot", sources,
                                                            np.arange(0, 2930, 7)))

    def test_errors_map_to_exceptions(self):
        gc, c = self.gc, self.client
        with self.assertRaises(gc.OutOfRangeError) as e:
            c.distances("spot", [999999], [1])
        self.assertIsInstance(e.exception, __import__("grpc").RpcError)
        self.assertEqual(e.exception.code().name, "OUT_OF_RANGE")
        with self.assertRaises(gc.NotFoundError):
            c.distance("nosuch", 1, 2)
        with self.assertRaises(gc.InvalidArgumentError):
            c.distances("spot", gc.FacePoints([1], [[0.5, 0.5, 0.5]]), [2])
        # A graph nobody requested, at another epsilon than the server's default, is not
        # started by a query: the error says to request it, and then the query answers.
        with self.assertRaises(gc.FailedPreconditionError) as e:
            gc.Client(f"127.0.0.1:{self.port}", epsilon=0.3).distance("spot", 1, 2)
        self.assertIn("RequestGraph", e.exception.details())
        c.request_graph("spot", epsilon=0.3, wait=True)
        first = gc.Client(f"127.0.0.1:{self.port}", epsilon=0.3).distance("spot", 1, 2)
        self.assertTrue(np.isfinite(first) and first > 0, first)
        self.assertEqual(first, gc.Client(f"127.0.0.1:{self.port}", epsilon=0.3).distance(
            "spot", 1, 2))
        with self.assertRaises(ValueError):
            c.distances("spot", [1, 2], [3])
        with self.assertRaises(ValueError):
            c.distances("spot", np.zeros((4, 2)), [1, 2, 3, 4])

    def test_graph_states_are_enums(self):
        g = self.client.graph("spot")
        self.assertIs(g.state, self.gc.GraphState.READY)
        self.assertEqual(g.epsilon, EPS)
        self.assertIn(("spot", EPS, self.gc.GraphState.READY),
                      [(x.mesh, x.epsilon, x.state) for x in self.client.graphs()])

    def test_unavailable_is_retried_while_a_graph_builds(self):
        # A fresh graph is still building when the query arrives: UNAVAILABLE, then served.
        g = self.client.request_graph("spot", epsilon=0.2, wait=False)
        self.assertIsInstance(g.state, self.gc.GraphState)
        d = self.client.distance("spot", 1, 2000, epsilon=0.2)
        self.assertGreater(d, 0)
        self.assertIs(self.client.graph("spot", 0.2).state, self.gc.GraphState.READY)


class RetryTest(unittest.TestCase):
    """Against an in-process server that is UNAVAILABLE for its first calls."""

    def serve(self, failures):
        import grpc
        from geodesic_client._stubs import pb, rpc
        calls = []

        class Flaky(rpc.GeodesicServicer):
            def ListMeshes(self, request, context):
                calls.append(time.monotonic())
                if len(calls) <= failures:
                    context.abort(grpc.StatusCode.UNAVAILABLE, "warming up")
                return pb.ListMeshesResponse(meshes=[pb.Mesh(name="m")])

        server = grpc.server(futures.ThreadPoolExecutor(max_workers=2))
        rpc.add_GeodesicServicer_to_server(Flaky(), server)
        port = server.add_insecure_port("127.0.0.1:0")
        server.start()
        self.addCleanup(server.stop, None)
        return port, calls

    def test_retried_with_growing_backoff(self):
        import geodesic_client as gc
        port, calls = self.serve(failures=3)
        policy = gc.RetryPolicy(max_attempts=5, initial_backoff=0.05, multiplier=2)
        self.assertEqual([m.name for m in gc.Client(f"127.0.0.1:{port}", retry=policy).meshes()],
                         ["m"])
        self.assertEqual(len(calls), 4)
        gaps = np.diff(calls)
        self.assertGreaterEqual(gaps[0], 0.025)
        self.assertGreaterEqual(gaps[2], 0.1)  # third retry waits at least 0.2 / 2

    def test_bounded(self):
        import geodesic_client as gc
        port, calls = self.serve(failures=100)
        with self.assertRaises(gc.UnavailableError):
            gc.Client(f"127.0.0.1:{port}", retry=gc.RetryPolicy(max_attempts=3,
                                                                initial_backoff=0.01)).meshes()
        self.assertEqual(len(calls), 3)


if __name__ == "__main__":
    if sys.argv[3:4] == ["--inside"]:
        WORK = sys.argv[4]
        sys.path = [p for p in sys.path if not p.startswith(SRC)]
        unittest.main(argv=[sys.argv[0], "-v"])
    else:
        with tempfile.TemporaryDirectory() as work:
            started = time.time()
            venv = install(work)
            print(f"installed into a fresh venv in {time.time() - started:.1f} s", flush=True)
            r = subprocess.run([f"{venv}/bin/python", os.path.abspath(__file__), BIN, SRC,
                                "--inside", work], cwd=work)
            sys.exit(r.returncode)
