#!/usr/bin/python3
"""The installed layout serves on its own: `cmake --install` into a fresh
prefix, then the installed daemon, started from elsewhere with no
GEODESIC_DATA_DIR or GEODESIC_WEB_DIR, must find the bundled sample mesh and
the web viewer beside itself (P/share/geodesicd) and three.js from Debian's
libjs-three, as it does in the container image, which is this layout under
/usr/local.

Usage: install_layout_test.py CMAKE BUILD_DIR SOURCE_DIR
"""
import json
import os
import subprocess
import sys
import tempfile
import urllib.error
import urllib.request

CMAKE, BUILD, SRC = sys.argv[1], sys.argv[2], sys.argv[3]
sys.path.insert(0, os.path.join(SRC, "tests", "server"))
import daemon_ports  # noqa: E402
from daemon_ports import start_daemon  # noqa: E402

errors = []


def need(cond, message):
    if not cond:
        errors.append(message)


def get(port, path):
    """(HTTP status, body bytes) of a GET on the daemon's HTTP listener."""
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=30) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.read()


def main():
    for var in ("GEODESIC_DATA_DIR", "GEODESIC_WEB_DIR"):
        os.environ.pop(var, None)
    with tempfile.TemporaryDirectory() as work:
        prefix = os.path.join(work, "prefix")
        subprocess.run([CMAKE, "--install", BUILD, "--prefix", prefix], check=True,
                       stdout=subprocess.DEVNULL)
        for f in ("bin/geodesicd", "bin/geodesic", "share/geodesicd/spot.obj",
                  "share/geodesicd/web/index.html", "share/geodesicd/web/viewer.js",
                  "share/geodesicd/web/openapi.json"):
            need(os.path.isfile(os.path.join(prefix, f)), f"install: no {f}")
        if errors:
            return report()

        # Run from the work directory: nothing may be found relative to the
        # source tree or the current directory.
        os.chdir(work)
        daemon, ports = start_daemon(os.path.join(prefix, "bin"), work,
                                     ["--http-listen", "127.0.0.1:0", "--graph-dir",
                                      os.path.join(work, "graphs"), "--log-level", "warning"])
        try:
            http = ports.get("http")
            need(http, f"the port file names no HTTP port: {ports}")
            if http:
                status, body = get(http, "/v1/meshes")
                meshes = json.loads(body).get("meshes", []) if status == 200 else []
                need(any(m.get("name") == "spot" for m in meshes),
                     f"GET /v1/meshes: the bundled sample mesh is not served "
                     f"({status} {body[:200]!r})")
                status, body = get(http, "/")
                need(status == 200 and b"viewer.js" in body,
                     f"GET /: not the viewer's page ({status} {body[:200]!r})")
                status, body = get(http, "/three/build/three.module.js")
                need(status == 200 and len(body) > 100_000,
                     f"GET /three/build/three.module.js: {status}, {len(body)} bytes "
                     "(is libjs-three installed?)")
            status = subprocess.run([os.path.join(prefix, "bin", "geodesic"), "--server",
                                     f"127.0.0.1:{ports['grpc']}", "meshes"],
                                    capture_output=True, text=True, timeout=60)
            need(status.returncode == 0 and "spot" in status.stdout,
                 f"installed CLI: `geodesic meshes` gave {status.returncode}: "
                 f"{status.stdout[:200]}{status.stderr[:200]}")
        finally:
            daemon_ports.stop(daemon)
    return report()


def report():
    for e in errors:
        print("FAIL", e)
    print(f"installed layout: {len(errors)} problems")
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
