#!/usr/bin/python3
"""Bounded stress test: concurrent clients mixing fields, pairs, paths, builds,
uploads, unloads and evictions under a small memory limit. Every answer is
checked against the offline core result on the same graph; the daemon must not
crash, deadlock or grow in memory across repeated queries.

Usage: stress_test.py BUILD_BIN_DIR SOURCE_DIR [SECONDS]
"""
import json
import os
import random
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request

import numpy as np

BIN, SRC = sys.argv[1], sys.argv[2]
SECONDS = float(sys.argv[3]) if len(sys.argv) > 3 else 20
sys.path.insert(0, os.path.join(SRC, "client", "python"))
import grpc  # noqa: E402
from geodesic_client import Client  # noqa: E402
from daemon_ports import rss_bytes, start_daemon  # noqa: E402

MESH = f"{SRC}/data/spot.obj"
# Bytes of --memory-limit left for spot and the churning uploads of it
# (about 0.8 MB each as built).
MESH_ALLOWANCE = 4 << 20
# The gauges of what --memory-limit covers.
COUNTED = ("mesh_resident_bytes", "graph_resident_bytes", "graph_mapped_bytes",
           "query_scratch_bytes")
EPSILONS = (0.01, 0.02)
SOURCES = ["v:0", "v:777", "f:100:0.2,0.3,0.5", "e:40:0.25"]
PAIRS = [("v:1", "v:2000"), ("f:3:0.2,0.3,0.5", "v:100"), ("v:2929", "e:500:0.5"),
         ("f:5000:0.6,0.2,0.2", "f:10:0.1,0.1,0.8")]
# Codes a correct server may answer under this load: overload, and graphs
# evicted (UNAVAILABLE) or meshes unloaded (NOT_FOUND) by other clients.
RETRYABLE = {grpc.StatusCode.RESOURCE_EXHAUSTED, grpc.StatusCode.UNAVAILABLE}


def run(*args):
    return subprocess.run([f"{BIN}/geodesicd", *args], check=True, capture_output=True,
                          text=True).stdout


def offline_truth(work):
    """Fields and pair distances from the offline commands on offline-built graphs."""
    truth = {}
    pairs_file = f"{work}/pairs.txt"
    with open(pairs_file, "w") as f:
        f.writelines(f"{a} {b}\n" for a, b in PAIRS)
    for eps in EPSILONS:
        graph = f"{work}/offline-{eps}.dgg"
        run("build", MESH, "--eps", str(eps), "--out", graph, "--quiet")
        for s in SOURCES:
            out = f"{work}/field.f64"
            run("field", "--mesh", MESH, "--graph", graph, "--source", s, "--out", out)
            truth[("field", eps, s)] = np.fromfile(out)
        for r in json.loads(run("distance", "--mesh", MESH, "--graph", graph, "--pairs",
                                pairs_file, "--json")):
            truth[("pair", eps, r["from"], r["to"])] = r["distance"]
    return truth


def gauge(metrics_text, name):
    for line in metrics_text.splitlines():
        if line.startswith(name + " "):
            return float(line.split()[-1])
    raise AssertionError(f"{name} missing from /metrics")


class Stress:
    def __init__(self, client, truth):
        self.client, self.truth = client, truth
        self.errors, self.counts = [], {}
        self.lock = threading.Lock()

    def count(self, what):
        with self.lock:
            self.counts[what] = self.counts.get(what, 0) + 1

    def fail(self, message):
        with self.lock:
            self.errors.append(message)

    def with_graph(self, mesh, eps, call):
        """Runs call(); an evicted graph is requested again, overload is retried."""
        for attempt in range(20):
            try:
                return call()
            except grpc.RpcError as e:
                if e.code() not in RETRYABLE:
                    raise
                self.count(e.code().name)
                time.sleep(random.uniform(0, 0.01 * (attempt + 1)))
                if e.code() == grpc.StatusCode.UNAVAILABLE:
                    self.client.request_graph(mesh, epsilon=eps, wait=True)
        raise RuntimeError(f"{mesh} eps {eps}: still failing after 20 attempts")

    def query_worker(self, seed, deadline):
        rng = random.Random(seed)
        while time.time() < deadline and not self.errors:
            eps = rng.choice(EPSILONS)
            kind = rng.choice(["field", "pair", "path", "matrix"])
            try:
                if kind == "field":
                    s = rng.choice(SOURCES)
                    got = self.with_graph("spot", eps, lambda: self.client.field("spot", [s], eps))
                    if not np.array_equal(got, self.truth[("field", eps, s)]):
                        self.fail(f"field from {s} at eps {eps} differs from the offline field")
                elif kind in ("pair", "path"):
                    a, b = rng.choice(PAIRS)
                    want = self.truth[("pair", eps, a, b)]
                    if kind == "pair":
                        got = self.with_graph("spot", eps,
                                              lambda: self.client.distance("spot", a, b, eps))
                        if got != want:
                            self.fail(f"{a}->{b} at eps {eps}: {got!r} != offline {want!r}")
                    else:
                        length, points = self.with_graph(
                            "spot", eps, lambda: self.client.path("spot", a, b, eps))
                        if not (len(points) >= 2 and length <= want * (1 + 1e-6)):
                            self.fail(f"path {a}->{b}: length {length} vs distance {want}")
                else:
                    m = self.with_graph("spot", eps, lambda: self.client.matrix(
                        "spot", SOURCES[:2], ["v:5", "v:1500"], eps))
                    for i, s in enumerate(SOURCES[:2]):
                        field = self.truth[("field", eps, s)]
                        if not np.array_equal(m[i], field[[5, 1500]]):
                            self.fail(f"matrix row {s} at eps {eps} differs from the field")
                self.count(kind)
            except Exception as e:  # noqa: BLE001 - every unexpected failure is reported
                self.fail(f"{kind} at eps {eps}: {e!r}")

    def churn_worker(self, deadline):
        """Uploads, builds, queries and unloads a second mesh, over and over."""
        n = 0
        while time.time() < deadline and not self.errors:
            name = f"churn{n % 2}"
            n += 1
            try:
                self.client.upload_mesh(name, MESH)
                self.client.request_graph(name, epsilon=0.02, wait=True)
                got = self.with_graph(name, 0.02,
                                      lambda: self.client.distance(name, *PAIRS[0], 0.02))
                if got != self.truth[("pair", 0.02, *PAIRS[0])]:
                    self.fail(f"{name}: {got!r} differs from the offline distance")
                self.client.unload_mesh(name)
                self.count("churn")
            except Exception as e:  # noqa: BLE001
                self.fail(f"churn {name}: {e!r}")


def main():
    work = tempfile.mkdtemp()
    daemon = None
    try:
        truth = offline_truth(work)
        graph_bytes = sum(os.path.getsize(f"{work}/offline-{e}.dgg") for e in EPSILONS)
        # Room for the two graphs of spot and the meshes but not also the
        # churning mesh's graph: each of its builds evicts the least recently
        # used graph.
        memory_limit = int(graph_bytes * 1.1) + MESH_ALLOWANCE
        daemon, ports = start_daemon(
            BIN, work,
            ["--graph-dir", f"{work}/graphs", "--mesh-root", f"{SRC}/data", "--log-level",
             "warning", "--memory-limit", str(memory_limit), "--max-inflight", "6"],
            stderr=open(f"{work}/daemon.log", "w"), metrics=True)
        port, metrics_port = ports["grpc"], ports["metrics"]
        client = Client(f"127.0.0.1:{port}", timeout=60)
        for _ in range(100):
            try:
                client.meshes()
                break
            except grpc.RpcError:
                time.sleep(0.1)
        for eps in EPSILONS:
            client.request_graph("spot", epsilon=eps, wait=True)

        stress = Stress(client, truth)
        deadline = time.time() + SECONDS
        threads = [threading.Thread(target=stress.query_worker, args=(i, deadline))
                   for i in range(8)]
        threads.append(threading.Thread(target=stress.churn_worker, args=(deadline,)))
        for t in threads:
            t.start()
        for t in threads:
            t.join(timeout=SECONDS + 120)
        hung = [t for t in threads if t.is_alive()]
        print("operations:", json.dumps(stress.counts, sort_keys=True))
        ok = True
        if hung:
            print(f"FAIL {len(hung)} client threads still blocked: deadlock?")
            ok = False
        if daemon.poll() is not None:
            print(f"FAIL daemon exited with {daemon.returncode}")
            ok = False
        for e in stress.errors[:20]:
            print("FAIL", e)
        ok = ok and not stress.errors
        # Counted by the daemon itself: UNAVAILABLE answers also come from
        # graphs still building, so they prove nothing about eviction.
        metrics = urllib.request.urlopen(f"http://127.0.0.1:{metrics_port}/metrics",
                                         timeout=10).read().decode()
        evictions = max((float(line.split()[-1]) for line in metrics.splitlines()
                         if line.startswith("geodesicd_graph_evictions_total ")), default=0)
        print(f"graphs evicted: {evictions:.0f}")
        if evictions == 0:
            print("FAIL no graph was evicted: the memory limit was not exercised")
            ok = False
        # What the limit covers is counted, and stays within it but for the
        # one graph a build just made ready (never evicted at once).
        counted = {name: gauge(metrics, f"geodesicd_{name}") for name in COUNTED}
        print("counted bytes:", json.dumps(counted, sort_keys=True))
        for name in ("mesh_resident_bytes", "query_scratch_bytes"):
            if counted[name] <= 0:
                print(f"FAIL geodesicd_{name} is {counted[name]}: not counted")
                ok = False
        largest_graph = max(os.path.getsize(f"{work}/offline-{e}.dgg") for e in EPSILONS)
        if sum(counted.values()) > memory_limit + largest_graph:
            print(f"FAIL counted memory {sum(counted.values()):.0f} exceeds the limit "
                  f"{memory_limit} by more than one graph ({largest_graph})")
            ok = False
        # The process's own (anonymous) memory is what the gauges count
        # outside the mapped graph files, plus the daemon's fixed costs: no
        # buffer the queries left behind is invisible to the limit.
        anonymous = rss_bytes(daemon.pid, "RssAnon")
        counted_anonymous = sum(counted.values()) - counted["graph_mapped_bytes"]
        print(f"anonymous resident {anonymous >> 20} MiB, counted {int(counted_anonymous) >> 20} MiB")
        if anonymous > counted_anonymous + (64 << 20):
            print("FAIL the daemon holds more than 64 MiB its gauges do not count")
            ok = False

        # Memory stays flat across repeated queries on a resident graph.
        client.request_graph("spot", epsilon=0.01, wait=True)
        froms, tos = zip(*PAIRS)
        rounds = lambda k: [client.distances("spot", froms, tos, 0.01, with_path=True)  # noqa: E731
                            and client.field("spot", SOURCES[:1], 0.01) for _ in range(k)]
        rounds(300)
        before = rss_bytes(daemon.pid)
        rounds(1500)
        after = rss_bytes(daemon.pid)
        growth = (after - before) / before
        print(f"daemon RSS {before >> 20} MiB -> {after >> 20} MiB over 1500 more rounds "
              f"({100 * growth:+.1f}%)")
        if growth > 0.05:
            print("FAIL memory grows with repeated queries")
            ok = False

        daemon.terminate()
        try:
            daemon.wait(timeout=30)
        except subprocess.TimeoutExpired:
            print("FAIL daemon did not stop within 30 s of SIGTERM")
            ok = False
        print("stress test", "passed" if ok else "FAILED")
        if not ok:
            print(open(f"{work}/daemon.log").read()[-4000:])
        return 0 if ok else 1
    finally:
        if daemon and daemon.poll() is None:
            daemon.kill()
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
