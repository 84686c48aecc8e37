#!/usr/bin/python3
"""Certified graphs through the daemon: RequestGraph with max_error from the
Python client, the CLI and HTTP; the certificate in graph status, `status`,
the graph JSON, metrics and the sidecar beside the graph file; the catalog
records it, so a restart over the same --graph-dir maps it with its
certificate, asked by no client, instead of building; --config declares one
by `max_error`.

Usage: certified_graph_test.py BUILD_BIN_DIR SOURCE_DIR
"""
import json
import os
import subprocess
import sys
import tempfile
import time
import urllib.request

BIN, SRC = sys.argv[1], sys.argv[2]
sys.path.insert(0, os.path.join(SRC, "client", "python"))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from geodesic_client import Client, GraphCertificate, GraphState  # noqa: E402
import daemon_ports  # noqa: E402
from checklist import Checklist  # noqa: E402

BOUND = 1e-2
check = Checklist()


def serve(work, graphs, *args):
    log = open(os.path.join(work, "daemon.log"), "a")
    return daemon_ports.start_daemon(BIN, work, ["--graph-dir", graphs, "--log-level", "warning",
                                                 "--pseudo-vertex-limit", "0", *args],
                                     stderr=log, metrics=True, http=True)


def cli(port, *args):
    r = subprocess.run([f"{BIN}/geodesic", "--server", f"127.0.0.1:{port}", *args],
                       capture_output=True, text=True, timeout=300)
    return r.returncode, r.stdout, r.stderr


def http(port, path, body=None):
    req = urllib.request.Request(f"http://127.0.0.1:{port}{path}",
                                 data=None if body is None else json.dumps(body).encode(),
                                 method="GET" if body is None else "POST",
                                 headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(req, timeout=120) as r:
        return json.loads(r.read().decode())


def metric(port, name):
    page = urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=10).read().decode()
    for line in page.splitlines():
        if line.startswith(name + " "):
            return float(line.split()[1])
    return None


def good(c, bound=BOUND):
    return (isinstance(c, GraphCertificate) and c.sound and c.max_error_bound == bound and
            0 < c.measured_max_error <= bound and c.measured_mean_error <= c.measured_max_error and
            c.epsilon < bound and c.sources > 0 and c.builds >= 1)


with tempfile.TemporaryDirectory() as work:
    graphs = os.path.join(work, "graphs")
    daemon, ports = serve(work, graphs)
    try:
        with Client(f"127.0.0.1:{ports['grpc']}") as client:
            phases = []
            g = client.request_graph("spot", max_error=BOUND,
                                     progress=lambda s: phases.append(s.phase))
            check("request_graph(max_error=1e-2) is ready with a sound certificate",
                  g.state == GraphState.READY and good(g.certificate), g)
            check("its epsilon is the certificate's, below the bound",
                  g.epsilon == g.certificate.epsilon < BOUND and g.max_error == BOUND, g)
            check("the check is a phase of its making", "check" in phases, phases)
            plain = client.request_graph("spot", epsilon=g.epsilon)
            check("the plain graph of that epsilon is another graph, without a certificate",
                  plain.certificate is None and plain.max_error == 0 and not plain.from_file,
                  plain)
            listed = [x for x in client.graphs() if x.mesh == "spot"]
            check("both are listed, one of them certified",
                  [x.max_error for x in listed if x.epsilon == g.epsilon] in ([0, BOUND], [BOUND, 0])
                  and sum(x.certificate is not None for x in listed) == 1, listed)
            d = client.distance("spot", "v:0", "v:2000", max_error=BOUND)
            check("a query names the certified graph by its bound", d > 0, d)
            cert = g.certificate

        rc, out, err = cli(ports["grpc"], "--json", "--max-error", str(BOUND), "graph")
        graph = json.loads(out) if rc == 0 else {}
        check("the CLI's graph --json carries the certificate",
              rc == 0 and graph.get("certificate", {}).get("measured_max_error") ==
              cert.measured_max_error and graph.get("max_error") == BOUND, out + err)
        rc, out, err = cli(ports["grpc"], "status")
        check("the CLI's status prints it", rc == 0 and "certified: max error" in out, out + err)

        got = http(ports["http"], f"/v1/meshes/spot/graph?max_error={BOUND}")
        check("HTTP graph JSON carries the certificate",
              got["certificate"] is not None and got["certificate"]["sound"] is True and
              got["certificate"]["measured_max_error"] == cert.measured_max_error and
              got["max_error"] == BOUND, got)
        got = http(ports["http"], f"/v1/meshes/spot/graph?eps={cert.epsilon}")
        check("and a plain graph's is null", got["certificate"] is None, got)
        got = http(ports["http"], "/v1/meshes/spot/graph", {"max_error": BOUND})
        check("POST graph with max_error answers the certified graph",
              got["certificate"] is not None and got["state"] == "READY", got)
        got = http(ports["http"], "/v1/meshes/spot/distance",
                   {"max_error": BOUND, "pairs": [["v:0", "v:2000"]]})
        check("an HTTP query with max_error says it was answered by it",
              got.get("max_error") == BOUND and got.get("eps") == cert.epsilon, got)

        check("metrics count the certified graph",
              metric(ports["metrics"], "geodesicd_certified_graphs") == 1 and
              metric(ports["metrics"], "geodesicd_certified_graph_max_error") ==
              cert.measured_max_error, [metric(ports["metrics"], "geodesicd_certified_graphs"),
                                        metric(ports["metrics"], "geodesicd_certified_graph_max_error")])

        files = os.listdir(graphs)
        certified = [f for f in files if f.endswith(".dgg") and f"-cert{BOUND}-" in f]
        check("its file is named by the bound", len(certified) == 1, files)
        check("its certificate is beside it",
              certified and certified[0] + ".certificate.json" in files, files)
        if certified:
            r = subprocess.run([f"{BIN}/geodesicd", "info", "--json",
                                os.path.join(graphs, certified[0])],
                               capture_output=True, text=True, timeout=60)
            info = json.loads(r.stdout) if r.returncode == 0 else {}
            check("geodesicd info shows the daemon's certificate",
                  info.get("certificate", {}).get("measured_max_error") == cert.measured_max_error,
                  r.stdout[-800:] + r.stderr)
    finally:
        daemon_ports.stop(daemon)

    # The catalog records it with its bound (format version 2, which a
    # build before certified graphs refuses rather than misread).
    with open(os.path.join(graphs, "catalog.json")) as f:
        catalog = json.load(f)
    check("the catalog records the certified graph by its bound",
          catalog.get("version") == 2 and
          [g["mesh"] for g in catalog["graphs"] if g.get("max_error") == BOUND] == ["spot"],
          catalog)

    # A restart over the same directory maps it, certificate and all.
    daemon, ports = serve(work, graphs)
    try:
        with Client(f"127.0.0.1:{ports['grpc']}") as client:
            # Restored from the catalog: ready before any client asks.
            restored, deadline = [], time.time() + 60
            while time.time() < deadline:
                restored = [x for x in client.graphs() if x.mesh == "spot" and x.max_error == BOUND]
                if restored and restored[0].state == GraphState.READY:
                    break
                time.sleep(0.2)
            check("after a restart it is listed READY, asked by no one",
                  len(restored) == 1 and restored[0].state == GraphState.READY and
                  restored[0].from_file, restored)
            check("with its certificate", restored and restored[0].certificate == cert,
                  (restored and restored[0].certificate, cert))
            again = client.request_graph("spot", max_error=BOUND)
            check("after a restart it is mapped, not rebuilt",
                  again.state == GraphState.READY and again.from_file, again)
            check("with the same certificate", again.certificate == cert, (again.certificate, cert))
            check("no build ran", metric(ports["metrics"], "geodesicd_graph_builds_total") == 0,
                  metric(ports["metrics"], "geodesicd_graph_builds_total"))
    finally:
        daemon_ports.stop(daemon)

    # --config declares a certified graph by `max_error`: requested at
    # start, certified, and here mapped from the file the runs above left
    # (the declared mesh is spot's file, so its graphs are spot's).
    config = os.path.join(work, "deploy.yaml")
    spot = os.path.abspath(os.path.join(SRC, "data", "spot.obj"))
    with open(config, "w") as f:
        f.write(f"meshes:\n  - name: declared\n    path: {spot}\n"
                f"graphs:\n  - mesh: declared\n    max_error: {BOUND}\n")
    daemon, ports = serve(work, graphs, "--config", config)
    try:
        with Client(f"127.0.0.1:{ports['grpc']}") as client:
            declared, deadline = [], time.time() + 120
            while time.time() < deadline:
                declared = [x for x in client.graphs() if x.mesh == "declared"]
                if declared and declared[0].state == GraphState.READY:
                    break
                time.sleep(0.2)
            check("a --config graph with max_error is the certified graph, ready",
                  len(declared) == 1 and declared[0].state == GraphState.READY and
                  declared[0].max_error == BOUND and good(declared[0].certificate), declared)
            check("mapped with its certificate, not rebuilt",
                  declared and declared[0].from_file and declared[0].certificate == cert and
                  metric(ports["metrics"], "geodesicd_graph_builds_total") == 0,
                  (declared, metric(ports["metrics"], "geodesicd_graph_builds_total")))
    finally:
        daemon_ports.stop(daemon)
    with open(config, "a") as f:
        f.write("    eps: 0.004\n")
    r = subprocess.run([f"{BIN}/geodesicd", "serve", "--listen", "127.0.0.1:0", "--config", config],
                       capture_output=True, text=True, timeout=60)
    check("a --config graph with both eps and max_error is refused with file and line",
          r.returncode != 0 and "deploy.yaml:7:" in r.stderr and
          "gives both 'eps' and 'max_error'" in r.stderr, r.stderr)
    if check.failures:
        with open(os.path.join(work, "daemon.log")) as f:
            print(f.read()[-4000:])

check.finish()
