#!/usr/bin/env python3
"""What operators rely on (#23): registered meshes and requested graphs
survive SIGTERM and kill -9 and answer again at once, without rebuilding;
two replicas on one graph directory share them; --disk-limit never removes a
file in use; a port already taken is refused; sizes read as K/M/G; /healthz
and /readyz; a --config file; regions kept compactly in the catalog, and a
region whose parent is gone from it removed at the next start. Every daemon
listens on 127.0.0.1 port 0, and every wait is bounded.

Usage: durability_test.py BUILD_BIN_DIR SOURCE_DIR"""
import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(sys.argv[2], "client", "python"))
import daemon_ports  # noqa: E402
import grpc  # noqa: E402
from geodesic_client import Client, GeodesicError  # noqa: E402
from checklist import Checklist  # noqa: E402
from daemon_ports import start_daemon  # noqa: E402

bin_dir, src = sys.argv[1], sys.argv[2]
data = os.path.join(src, "data")
check = Checklist()


def cli(port, *args, timeout=120):
    r = subprocess.run([f"{bin_dir}/geodesic", "--server", f"127.0.0.1:{port}", "--json", *args],
                       capture_output=True, text=True, timeout=timeout)
    return r.returncode, (json.loads(r.stdout) if r.returncode == 0 and r.stdout.strip() else None), r.stderr


def serve(work, graphs, *extra, metrics=False):
    log = open(os.path.join(work, "daemon.log"), "a")
    daemon, ports = start_daemon(bin_dir, work, ["--graph-dir", graphs, "--mesh-root", data,
                                                 "--no-sample", "--log-level", "warning",
                                                 "--catalog-poll-seconds", "0.5",
                                                 "--pseudo-vertex-limit", "0", *extra],
                                 stderr=log, metrics=metrics)
    return daemon, ports


def stop(daemon, sig=signal.SIGTERM):
    daemon_ports.stop(daemon, sig, timeout=60)


def real(distance):
    """A distance answered: a finite positive number, not the None of a wait
    that timed out (two of which are equal)."""
    return (isinstance(distance, (int, float)) and not isinstance(distance, bool) and
            math.isfinite(distance) and distance > 0)


def same_distance(got, want):
    return real(got) and real(want) and got == want


def fan_of_vertex_0(path):
    """The face ids (0-based) of the faces around vertex 0 of an .obj: a disk."""
    faces = []
    with open(path) as f:
        for line in f:
            if line.startswith("f "):
                faces.append([int(c.split("/")[0]) - 1 for c in line.split()[1:]])
    return [i for i, face in enumerate(faces) if 0 in face], len(faces)


def catalog_of(graphs):
    with open(os.path.join(graphs, "catalog.json")) as f:
        return f.read()


def distance_within(port, mesh, seconds):
    """The first distance answer for `mesh` within `seconds`, or None."""
    deadline = time.time() + seconds
    while time.time() < deadline:
        rc, out, _ = cli(port, "--mesh", mesh, "--eps", "0.01", "distance",
                         "--from", "v:1", "--to", "v:2000", timeout=10)
        if rc == 0:
            return out[0]["distance"]
        time.sleep(0.05)
    return None


with tempfile.TemporaryDirectory() as work:
    graphs = os.path.join(work, "graphs")

    # A client registers kitten and asks for its graph.
    daemon, ports = serve(work, graphs)
    port = ports["grpc"]
    rc, _, err = cli(port, "--mesh", "kitten", "load", "spot.obj")
    check("kitten registered", rc == 0, err)
    rc, graph, err = cli(port, "--mesh", "kitten", "--eps", "0.01", "graph", "--wait")
    check("its graph ready", rc == 0 and graph["state"] == "ready", err)
    want = distance_within(port, "kitten", 10)
    check("kitten answers a distance", real(want), want)

    for how, sig in (("SIGTERM", signal.SIGTERM), ("kill -9", signal.SIGKILL)):
        stop(daemon, sig)
        started = time.time()
        daemon, ports = serve(work, graphs)
        got = distance_within(ports["grpc"], "kitten", 10)
        elapsed = time.time() - started
        check(f"after {how} kitten answers again within 2 s ({elapsed:.2f} s)",
              same_distance(got, want) and elapsed < 2, f"{got} vs {want}")
        rc, status, _ = cli(ports["grpc"], "--mesh", "kitten", "--eps", "0.01", "graph")
        check(f"after {how} the graph was mapped, not rebuilt",
              rc == 0 and status["from_file"] is True, status)

    # A second replica on the same directory answers for kitten without the
    # client registering anything, and follows an unload made on the first.
    replica, replica_ports = serve(work, graphs)
    got = distance_within(replica_ports["grpc"], "kitten", 10)
    check("a replica answers for a mesh registered on another", same_distance(got, want), got)
    rc, _, err = cli(ports["grpc"], "--mesh", "puppy", "load", "spot.obj")
    rc2, _, err2 = cli(ports["grpc"], "--mesh", "puppy", "--eps", "0.02", "graph", "--wait")
    check("puppy registered and built on the first", rc == 0 and rc2 == 0, err + err2)
    deadline, names = time.time() + 10, []
    while time.time() < deadline and "puppy" not in names:
        _, listed, _ = cli(replica_ports["grpc"], "meshes")
        names = [m["name"] for m in listed or []]
        time.sleep(0.2)
    check("the replica follows a registration made on the first", "puppy" in names, names)
    rc, _, err = cli(ports["grpc"], "--mesh", "puppy", "unload")
    deadline = time.time() + 10
    while time.time() < deadline and "puppy" in names:
        _, listed, _ = cli(replica_ports["grpc"], "meshes")
        names = [m["name"] for m in listed or []]
        time.sleep(0.2)
    check("and an unload", rc == 0 and "puppy" not in names, names)
    stop(replica)

    # The catalog is one versioned JSON file; what a client was told is
    # ready is in it.
    with open(os.path.join(graphs, "catalog.json")) as f:
        catalog = json.load(f)
    check("the catalog lists kitten and its graph",
          [m["name"] for m in catalog["meshes"]] == ["kitten"] and
          [(g["mesh"], g["epsilon"]) for g in catalog["graphs"]] == [("kitten", 0.01)], catalog)

    # A second daemon on the same port is refused, by name.
    r = subprocess.run([f"{bin_dir}/geodesicd", "serve", "--listen", f"127.0.0.1:{ports['grpc']}",
                        "--graph-dir", os.path.join(work, "other"), "--no-sample"],
                       capture_output=True, text=True, timeout=60)
    check("a port already taken is refused", r.returncode != 0 and "cannot listen on" in r.stderr,
          r.stderr[-300:])
    stop(daemon)

    # --disk-limit: spare files (graphs of meshes nobody registered, old
    # snapshots) go, least recently used first; files in use stay.
    for name, age in (("00000000000000aa-eps0.01-r2.dgg", 300), ("00000000000000bb.mesh", 200)):
        path = os.path.join(graphs, name)
        with open(path, "wb") as f:
            f.write(b"x" * 4_000_000)
        os.utime(path, (time.time() - age, time.time() - age))
    # kitten's graph and snapshot are in use; puppy's graph (unloaded) is not.
    in_use = sorted(f for f in os.listdir(graphs)
                    if (f.endswith(".mesh") or "eps0.01-" in f) and "000000" not in f)
    spare = [f for f in os.listdir(graphs) if "eps0.02-" in f]
    for f in spare:  # files written in the last two minutes are never removed
        os.utime(os.path.join(graphs, f), (time.time() - 400, time.time() - 400))
    daemon, ports = serve(work, graphs, "--disk-limit", "3M", "--memory-limit", "6G", metrics=True)
    distance_within(ports["grpc"], "kitten", 10)
    deadline = time.time() + 10
    while time.time() < deadline and any("000000" in f for f in os.listdir(graphs)):
        time.sleep(0.2)
    left = os.listdir(graphs)
    check("spare files removed to meet --disk-limit",
          not any("000000" in f or f in spare for f in left), left)
    check("files in use kept although over the limit", all(f in left for f in in_use), (in_use, left))
    got = distance_within(ports["grpc"], "kitten", 5)
    check("queries still answer", same_distance(got, want), f"{got} vs {want}")
    metrics_url = f"http://127.0.0.1:{ports['metrics']}"
    page = urllib.request.urlopen(metrics_url + "/metrics", timeout=10).read().decode()
    check("disk use and removals are metrics",
          "geodesicd_graph_dir_bytes " in page and
          f"geodesicd_disk_files_removed_total {2 + len(spare)}" in page,
          [l for l in page.splitlines() if "disk" in l])
    version = open(os.path.join(src, "VERSION")).read().strip()
    check("the build's version is a metric",
          re.search(r'^geodesicd_build_info\{build_type="\w+",version="' + re.escape(version)
                    + r'"\} 1$', page, re.M) is not None,
          [l for l in page.splitlines() if "build_info" in l])
    for path, want_status in (("/healthz", 200), ("/readyz", 200)):
        try:
            status = urllib.request.urlopen(metrics_url + path, timeout=10).status
        except urllib.error.HTTPError as e:
            status = e.code
        check(f"{path} answers {want_status}", status == want_status, status)
    stop(daemon)

    # An uploaded mesh whose snapshot (its only copy) is lost while the daemon
    # is down: queries say so, and unloading and uploading again recovers.
    lost = os.path.join(work, "lost-graphs")
    daemon, ports = serve(work, lost)
    rc, _, err = cli(ports["grpc"], "--mesh", "sent", "load", "--upload", os.path.join(data, "spot.obj"))
    check("sent uploaded", rc == 0, err)
    stop(daemon)
    for f in os.listdir(lost):
        if f.endswith(".mesh"):
            os.remove(os.path.join(lost, f))
    daemon, ports = serve(work, lost)
    for _ in range(3):  # each a catalog read, not another restore
        rc, _, err = cli(ports["grpc"], "--mesh", "sent", "--eps", "0.01", "distance",
                         "--from", "v:1", "--to", "v:2000")
    check("a mesh that failed to restore is named as such",
          rc != 0 and "UNAVAILABLE" in err and "could not be restored here" in err, err)
    with open(os.path.join(work, "daemon.log")) as f:
        restore_failures = f.read().count("catalog_mesh_restore_failed")
    check("and its restore is not retried by every query", restore_failures <= 2, restore_failures)
    rc, _, err = cli(ports["grpc"], "--mesh", "sent", "unload")
    _, _, gone = cli(ports["grpc"], "--mesh", "sent", "--eps", "0.01", "distance",
                     "--from", "v:1", "--to", "v:2000")
    check("once unloaded it is simply not found", "NOT_FOUND" in gone, gone)
    rc2, _, err2 = cli(ports["grpc"], "--mesh", "sent", "load", "--upload",
                       os.path.join(data, "spot.obj"))
    rc3, _, err3 = cli(ports["grpc"], "--mesh", "sent", "--eps", "0.01", "graph", "--wait")
    check("unloading and uploading again recovers it",
          rc == 0 and rc2 == 0 and rc3 == 0 and
          same_distance(distance_within(ports["grpc"], "sent", 10), want),
          err + err2 + err3)
    stop(daemon)

    # Regions (#67 item 7): a region of ids repeated a thousand times is the
    # region of the ids once, and the catalog records them once, as runs;
    # ids past reason are refused before any work.
    regions = os.path.join(work, "region-graphs")
    daemon, ports = serve(work, regions)
    rc, _, err = cli(ports["grpc"], "--mesh", "kitten", "load", "spot.obj")
    check("a parent registered", rc == 0, err)
    fan, face_count = fan_of_vertex_0(os.path.join(data, "spot.obj"))
    with Client(f"127.0.0.1:{ports['grpc']}", timeout=120) as client:
        plain = client.register_region("fan", "kitten", faces=fan)
        repeated = client.register_region("fan_x1000", "kitten", faces=fan[::-1] * 1000)
        check("ids repeated 1000 times cut the same region",
              repeated.fingerprint == plain.fingerprint, (repeated, plain))
        try:
            client.register_region("flood", "kitten", faces=[fan[0]] * (4 * face_count + 1))
            refused = None
        except GeodesicError as e:
            refused = e
        check("more than 4 ids per parent face are refused by name",
              refused is not None and refused.code() == grpc.StatusCode.INVALID_ARGUMENT and
              "list each id once" in refused.details(), refused)
    text = catalog_of(regions)
    catalog = json.loads(text)
    entry = [m for m in catalog["meshes"] if m["name"] == "fan_x1000"]
    check("the catalog records the region's ids once, compactly",
          catalog["version"] == 4 and len(entry) == 1 and
          entry[0]["region"].get("count") == len(fan) and len(text) < 4096,
          (len(text), entry))
    stop(daemon)

    # The region's parent gone from the catalog while the daemon is down (an
    # older build, a hand edit): the next start removes the regions from the
    # catalog, with a warning, rather than fail on them at every poll.
    catalog["meshes"] = [m for m in catalog["meshes"] if m["name"] != "kitten"]
    catalog["graphs"] = [g for g in catalog["graphs"] if g["mesh"] != "kitten"]
    with open(os.path.join(regions, "catalog.json"), "w") as f:
        json.dump(catalog, f)
    daemon, ports = serve(work, regions)
    deadline, left = time.time() + 10, None
    while time.time() < deadline:
        left = [m["name"] for m in json.loads(catalog_of(regions))["meshes"]]
        if not left:
            break
        time.sleep(0.2)
    with open(os.path.join(work, "daemon.log")) as f:
        orphaned = [line for line in f if "catalog_region_orphaned" in line]
    check("regions whose parent is gone are removed from the catalog, with a warning",
          left == [] and len(orphaned) == 2 and all("parent=kitten" in l for l in orphaned),
          (left, orphaned))
    _, listed, _ = cli(ports["grpc"], "meshes")
    check("and are not served", [m["name"] for m in listed or []] == [], listed)
    stop(daemon)

    r = subprocess.run([f"{bin_dir}/geodesicd", "serve", "--listen", "127.0.0.1:0",
                        "--memory-limit", "6 lots"], capture_output=True, text=True, timeout=60)
    check("a bad size is refused by flag and value",
          r.returncode != 0 and "--memory-limit: '6 lots' is not a size" in r.stderr, r.stderr)

    # --config: meshes and graphs declared by the deployment.
    config = os.path.join(work, "deploy.yaml")
    with open(config, "w") as f:
        f.write("meshes:\n  - name: declared\n    path: spot.obj\n"
                "graphs:\n  - mesh: declared\n    eps: 0.02\n")
    daemon, ports = serve(work, os.path.join(work, "config-graphs"), "--config", config)
    deadline, state = time.time() + 60, None
    while time.time() < deadline and state != "ready":
        _, status, _ = cli(ports["grpc"], "--mesh", "declared", "--eps", "0.02", "graph")
        state = status and status["state"]
        time.sleep(0.2)
    check("a --config mesh and graph are served", state == "ready", state)
    # A graph a client asked of a mesh the daemon registers itself (config,
    # sample) is requested again after a restart, with no query.
    rc, graph, err = cli(ports["grpc"], "--mesh", "declared", "--eps", "0.03", "graph", "--wait")
    check("a client's graph of a --config mesh is ready", rc == 0 and graph["state"] == "ready",
          err)
    stop(daemon)
    daemon, ports = serve(work, os.path.join(work, "config-graphs"), "--config", config)
    deadline, listed = time.time() + 60, []
    while time.time() < deadline:
        _, graphs_now, _ = cli(ports["grpc"], "status")
        listed = [(g["epsilon"], g["state"]) for g in graphs_now or [] if g["mesh"] == "declared"]
        if (0.03, "ready") in listed:
            break
        time.sleep(0.2)
    check("after a restart it is ready again, asked by no one", (0.03, "ready") in listed, listed)
    stop(daemon)
    bad = os.path.join(work, "bad.yaml")
    with open(bad, "w") as f:
        f.write("graphs:\n  - mesh: declared\n    eps: 0.02\n    pseudo: true\n")
    r = subprocess.run([f"{bin_dir}/geodesicd", "serve", "--listen", "127.0.0.1:0", "--config", bad],
                       capture_output=True, text=True, timeout=60)
    check("a bad --config is refused with file and line", r.returncode != 0 and "bad.yaml:" in r.stderr,
          r.stderr)
    if check.failures:
        with open(os.path.join(work, "daemon.log")) as f:
            print(f.read()[-4000:])

check.finish()
