#!/usr/bin/env python3
"""Build admission and the graph directory's limits (#34): --disk-limit
refuses an upload and a graph file that would pass it, --max-graph-bytes
refuses a graph from its estimate at once, and two replicas sharing a graph
directory build a graph once. With --full-disk (root: it mounts a small
tmpfs; exit 77, skipped, without root, and a failure as root if the mount
fails): an unload succeeds on a full disk.
Every daemon listens on 127.0.0.1 port 0, and every wait is bounded.

Usage: limits_test.py BUILD_BIN_DIR SOURCE_DIR [--full-disk]"""
import json
import os
import re
import subprocess
import sys
import tempfile
import time
import urllib.request

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import daemon_ports  # noqa: E402
from checklist import Checklist  # noqa: E402
from daemon_ports import start_daemon  # noqa: E402

bin_dir, src = os.path.abspath(sys.argv[1]), os.path.abspath(sys.argv[2])
full_disk = "--full-disk" in sys.argv[3:]
data = os.path.join(src, "data")
check = Checklist()
RESERVE = ".geodesicd-reserve"


def cli(port, *args, timeout=120):
    r = subprocess.run([f"{bin_dir}/geodesic", "--server", f"127.0.0.1:{port}", "--json", *args],
                       capture_output=True, text=True, timeout=timeout)
    out = None
    if r.returncode == 0 and r.stdout.strip():
        out = json.loads(r.stdout)
    return r.returncode, out, r.stderr


started = []  # every daemon, killed at exit whatever happens


def serve(work, graphs, *extra, metrics=False):
    log = open(os.path.join(work, "daemon.log"), "a")
    daemon, ports = start_daemon(bin_dir, work, ["--graph-dir", graphs, "--mesh-root", data,
                                                 "--no-sample", "--log-level", "info",
                                                 "--catalog-poll-seconds", "0.5", *extra],
                                 stderr=log, metrics=metrics)
    started.append(daemon)
    return daemon, ports


def stop(daemon):
    daemon_ports.stop(daemon, timeout=60)


def counted_bytes(graphs):
    """What --disk-limit counts: every file but the catalog's reserve."""
    return sum(os.path.getsize(os.path.join(graphs, f)) for f in os.listdir(graphs)
               if f != RESERVE and os.path.isfile(os.path.join(graphs, f)))


def graph_until(port, eps, states, seconds=120):
    """spot's graph at `eps` once in one of `states` (listed: asking with
    RequestGraph would start a failed graph again)."""
    deadline, g = time.time() + seconds, None
    while time.time() < deadline:
        rc, listed, _ = cli(port, "status", timeout=30)
        for item in listed or []:
            if item["mesh"] == "spot" and item["epsilon"] == float(eps):
                g = item
        if g is not None and g["state"] in states:
            return g
        time.sleep(0.1)
    return g


def metric(port, name):
    page = urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=10).read().decode()
    m = re.search(rf"^{name} (\S+)$", page, re.M)
    return float(m.group(1)) if m else None


def limits(work):
    # An upload whose snapshot would pass --disk-limit is refused, and
    # leaves nothing behind.
    graphs = os.path.join(work, "tiny")
    daemon, ports = serve(work, graphs, "--disk-limit", "64K")
    rc, _, err = cli(ports["grpc"], "--mesh", "spot", "load", "--upload", f"{data}/spot.obj")
    check("an upload over --disk-limit is refused", rc != 0 and "RESOURCE_EXHAUSTED" in err and
          "--disk-limit" in err, (rc, err))
    # An empty list, not a failed call: the daemon must answer.
    _, meshes, err = cli(ports["grpc"], "meshes")
    check("and not registered", meshes == [], meshes if meshes is not None else err)
    check("the directory stays within the limit", counted_bytes(graphs) <= 64 << 10,
          os.listdir(graphs))
    stop(daemon)

    # A 3M directory with the upload in it (its snapshot is the only copy:
    # never evicted), and at most 10M per graph.
    graphs = os.path.join(work, "graphs")
    daemon, ports = serve(work, graphs, "--disk-limit", "3M", "--max-graph-bytes", "10M",
                          "--build-threads", "1")
    port = ports["grpc"]
    rc, _, err = cli(port, "--mesh", "spot", "load", "--upload", f"{data}/spot.obj")
    check("an upload within --disk-limit is registered", rc == 0, err)

    started = time.time()
    rc, _, err = cli(port, "--mesh", "spot", "--eps", "1e-4", "graph")
    check("a graph over --max-graph-bytes is refused at once",
          rc != 0 and time.time() - started < 10 and "RESOURCE_EXHAUSTED" in err and
          "--max-graph-bytes" in err and "estimated at" in err and "larger epsilon" in err,
          (rc, err))
    rc, _, err = cli(port, "--mesh", "spot", "--eps", "5e-4", "graph")
    check("a graph that cannot fit --disk-limit is refused at once",
          rc != 0 and "RESOURCE_EXHAUSTED" in err and "--disk-limit" in err, (rc, err))
    _, listed, _ = cli(port, "status")
    check("refused graphs are not queued", not any(
        g.get("epsilon") in (1e-4, 5e-4) for g in (listed or [])), listed)

    # Admitted by its least size, but its file does not fit beside the
    # upload's snapshot: not written, and the graph fails saying why.
    rc, _, err = cli(port, "--mesh", "spot", "--eps", "1e-3", "graph")
    check("a graph that might fit is admitted", rc == 0, err)
    g = graph_until(port, "1e-3", ("failed", "ready"))
    check("its file would pass --disk-limit: the graph fails naming the sizes",
          g is not None and g["state"] == "failed" and "--disk-limit" in g["error"] and
          re.search(r"\d{6,} bytes", g["error"]), g)
    check("no graph file was written", not any(f.endswith(".dgg") or ".dgg.tmp." in f
                                              for f in os.listdir(graphs)), os.listdir(graphs))
    check("the directory stays within the limit", counted_bytes(graphs) <= 3 << 20,
          counted_bytes(graphs))
    rc, _, err = cli(port, "--mesh", "spot", "--eps", "1e-3", "graph")
    check("asked again, it is refused at once for its real size",
          rc != 0 and "RESOURCE_EXHAUSTED" in err and "--disk-limit" in err, (rc, err))
    rc, _, err = cli(port, "--mesh", "spot", "--eps", "0.01", "graph", "--wait")
    g = graph_until(port, "0.01", ("failed", "ready"))
    check("a graph that fits is built and kept", g is not None and g["state"] == "ready", g)
    stop(daemon)

    # Temporary files of killed writes go at start once they are old; young
    # ones may be a live replica's.
    old = [os.path.join(graphs, n) for n in ("catalog.json.tmp.4242.beef",
                                             "00aa.mesh.tmp.4242.cafe")]
    young = os.path.join(graphs, "catalog.json.tmp.4343.f00d")
    for path in old + [young]:
        with open(path, "w") as f:
            f.write("partial")
    for path in old:
        os.utime(path, (time.time() - 3600, time.time() - 3600))
    daemon, ports = serve(work, graphs)
    check("old temporary files are removed at start", not any(os.path.exists(p) for p in old),
          os.listdir(graphs))
    check("a young one is left alone", os.path.exists(young))
    stop(daemon)


def replicas(work):
    # Two replicas on one directory ask for one graph while it builds: one
    # builds, the other waits for it and maps the file.
    graphs = os.path.join(work, "shared")
    # A graph slow enough to build that the second replica finds it building:
    # below --min-epsilon's default.
    one, one_ports = serve(work, graphs, "--build-threads", "1", "--min-epsilon", "1e-5",
                           metrics=True)
    two, two_ports = serve(work, graphs, "--build-threads", "1", "--min-epsilon", "1e-5",
                           metrics=True)
    rc, _, err = cli(one_ports["grpc"], "--mesh", "spot", "load", "spot.obj")
    check("spot registered on the first replica", rc == 0, err)
    eps = "3e-5"
    rc, _, err = cli(one_ports["grpc"], "--mesh", "spot", "--eps", eps, "graph")
    building = graph_until(one_ports["grpc"], eps, ("building", "persisting", "ready", "failed"))
    check("the first replica is building", building and building["state"] == "building",
          building)
    rc, waiting, err = cli(two_ports["grpc"], "--mesh", "spot", "--eps", eps, "graph")
    check("the second replica's request is accepted", rc == 0, err)
    time.sleep(1)
    rc, waiting, err = cli(two_ports["grpc"], "--mesh", "spot", "--eps", eps, "graph")
    check("the second waits for the first's build",
          rc == 0 and waiting["state"] in ("queued", "ready") and
          (waiting["state"] == "ready" or "another replica" in waiting["phase"]), waiting or err)
    first = graph_until(one_ports["grpc"], eps, ("ready", "failed"), 240)
    second = graph_until(two_ports["grpc"], eps, ("ready", "failed"), 60)
    check("both end ready", first and second and first["state"] == second["state"] == "ready",
          (first, second))
    check("the second mapped the first's file", second and second["from_file"] is True, second)
    builds = [metric(one_ports["metrics"], "geodesicd_graph_builds_total"),
              metric(two_ports["metrics"], "geodesicd_graph_builds_total")]
    check("exactly one build happened", builds == [1, 0], builds)
    check("no lock file is left", not any(f.endswith(".lock") and ".dgg" in f
                                          for f in os.listdir(graphs)), os.listdir(graphs))
    stop(one)
    stop(two)


def full(work):
    # A disk really full: an unload must still go through (it frees space).
    mnt = os.path.join(work, "full")
    os.makedirs(mnt)
    if os.geteuid() != 0:
        print("skip: mounting a tmpfs needs root")
        return 77
    # CI runs as root: there a mount that fails is a failure, not a skip.
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=16m", "tmpfs", mnt],
                             capture_output=True, text=True)
    if mounted.returncode != 0:
        check("a tmpfs mounts (as root)", False, mounted.stderr)
        return 1
    try:
        daemon, ports = serve(work, mnt)
        port = ports["grpc"]
        check("the catalog keeps a reserve", os.path.exists(os.path.join(mnt, RESERVE)))
        rc, _, err = cli(port, "--mesh", "spot", "load", "spot.obj")
        check("spot registered", rc == 0, err)
        g = cli(port, "--mesh", "spot", "--eps", "0.01", "graph", "--wait")[1]
        check("its graph ready", g and g["state"] == "ready", g)
        with open(os.path.join(mnt, "filler"), "wb") as f:
            try:
                while True:
                    f.write(b"f" * (1 << 16))
                    f.flush()
            except OSError:
                pass
        rc, _, err = cli(port, "--mesh", "spot", "--eps", "0.02", "graph")
        check("the disk is full: a request cannot be recorded", rc != 0, err)
        rc, _, err = cli(port, "--mesh", "spot", "unload")
        check("an unload succeeds on a full disk", rc == 0, err)
        _, meshes, err = cli(port, "meshes")
        check("and spot is gone", meshes == [], meshes if meshes is not None else err)
        with open(os.path.join(mnt, "catalog.json")) as f:
            check("from the catalog too", json.load(f)["meshes"] == [])
        stop(daemon)
    finally:
        subprocess.run(["umount", mnt])
    return 0


with tempfile.TemporaryDirectory() as work:
    try:
        if full_disk:
            if full(work) == 77:
                sys.exit(77)
        else:
            limits(work)
            replicas(work)
    finally:
        for d in started:
            if d.poll() is None:
                d.kill()
                d.wait(timeout=30)
        if check.failures and os.path.exists(os.path.join(work, "daemon.log")):
            with open(os.path.join(work, "daemon.log")) as f:
                print("--- daemon log\n" + f.read()[-20000:])
check.finish()
