#!/usr/bin/env python3
"""The container image's runtime packages follow from the binaries.

Reads deploy/Dockerfile and checks, without docker:
- the runtime stage installs exactly the Debian packages that own the shared
  libraries the two binaries link directly (readelf NEEDED, resolved by ldd,
  owned per dpkg -S), besides those every debian:12-slim has and a short list
  of non-library packages named below; a library the binaries need and the
  image lacks fails, and so does a library package nothing needs;
- the build stage installs only what building needs (setup.sh --build-only:
  no browser, no test packages);
- the HEALTHCHECK uses the gRPC health check, which needs no bearer token;
- the image copies the installed layout and starts the daemon.

Usage: dockerfile_test.py BUILD_BIN_DIR SOURCE_DIR
"""
import os
import re
import shlex
import subprocess
import sys

# In every debian:12-slim image (essential, or what apt itself needs).
BASE_IMAGE = {"libc6", "libgcc-s1", "libstdc++6", "zlib1g"}
# Listed on purpose though no binary links them.
NOT_LIBRARIES = {"ca-certificates": "TLS roots for clients of the daemon's own calls",
                 "libjs-three": "three.js, which the viewer loads from /usr/share/javascript"}
BINARIES = ("geodesicd", "geodesic")

failures = []


def check(name, ok, detail=""):
    print(("ok   " if ok else "FAIL ") + name + ("" if ok else ": " + detail))
    if not ok:
        failures.append(name)


def stages(dockerfile):
    """{stage name: [instruction lines, continuations joined]}"""
    text = re.sub(r"\\\n", " ", open(dockerfile).read())
    out, current = {}, None
    for line in text.splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        m = re.match(r"FROM\s+\S+(?:\s+AS\s+(\S+))?", line, re.I)
        if m:
            current = m.group(1) or "unnamed"
            out[current] = []
            continue
        if current:
            out[current].append(line)
    return out


def apt_installed(lines):
    packages = set()
    for line in lines:
        if not line.upper().startswith("RUN"):
            continue
        for command in re.split(r"&&|;", line[3:]):
            words = shlex.split(command)
            if "apt-get" in words and "install" in words:
                after = words[words.index("install") + 1:]
                packages.update(w for w in after if not w.startswith("-"))
    return packages


def needed_packages(binary):
    needed = re.findall(r"\(NEEDED\)\s+Shared library: \[([^\]]+)\]",
                        subprocess.run(["readelf", "-d", binary], capture_output=True,
                                       text=True, check=True).stdout)
    resolved = {}
    for line in subprocess.run(["ldd", binary], capture_output=True, text=True,
                               check=True).stdout.splitlines():
        m = re.match(r"\s*(\S+)\s+=>\s+(\S+)", line)
        if m:
            resolved[m.group(1)] = m.group(2)
    packages = {}
    for soname in needed:
        if soname.startswith("ld-linux"):
            continue  # the dynamic loader, libc6's
        path = resolved.get(soname)
        if not path or path == "not":
            check(f"{os.path.basename(binary)} finds {soname}", False, "ldd cannot resolve it")
            continue
        owner = None
        real = os.path.realpath(path)
        candidates = [path, real]
        for p in list(candidates):
            if p.startswith("/usr/"):
                candidates.append(p[4:])
            else:
                candidates.append("/usr" + p)
        for p in candidates:
            r = subprocess.run(["dpkg", "-S", p], capture_output=True, text=True)
            if r.returncode == 0:
                owner = r.stdout.split(":")[0].strip()
                break
        if owner is None:
            check(f"{soname} belongs to a Debian package", False, f"dpkg -S {path} found none")
            continue
        packages[owner] = soname
    return packages


def main():
    bin_dir, src = sys.argv[1], sys.argv[2]
    dockerfile = os.path.join(src, "deploy", "Dockerfile")
    st = stages(dockerfile)
    check("the Dockerfile has a build and a runtime stage", "build" in st and "runtime" in st,
          f"stages: {sorted(st)}")
    if failures:
        return 1
    runtime = apt_installed(st["runtime"])
    needed = {}
    for name in BINARIES:
        binary = os.path.join(bin_dir, name)
        check(f"{name} is built", os.access(binary, os.X_OK), binary)
        if os.access(binary, os.X_OK):
            needed.update(needed_packages(binary))
    check("the binaries link some libraries", len(needed) > 3, f"found {needed}")
    wanted = {p for p in needed if p not in BASE_IMAGE}
    missing = sorted(wanted - runtime)
    check("the runtime stage installs every library the binaries link", not missing,
          "missing " + ", ".join(f"{p} (for {needed[p]})" for p in missing))
    extra = sorted(runtime - wanted - set(NOT_LIBRARIES))
    check("the runtime stage installs no library the binaries do not link", not extra,
          "not needed: " + ", ".join(extra))

    build_runs = " ".join(l for l in st["build"] if l.upper().startswith("RUN"))
    check("the build stage installs build packages only",
          "setup.sh --deps --build-only" in build_runs and "chromium" not in build_runs,
          build_runs[:200])
    setup = open(os.path.join(src, "scripts", "setup.sh")).read()
    build_list = re.search(r"BUILD_PACKAGES=\(([^)]*)\)", setup)
    check("setup.sh's build packages hold no browser or test package",
          build_list is not None and not re.search(r"chromium|selenium|gtest|gmock|cgal",
                                                   build_list.group(1)),
          build_list.group(1) if build_list else "no BUILD_PACKAGES list")

    health = [l for l in st["runtime"] if l.upper().startswith("HEALTHCHECK")]
    check("a HEALTHCHECK that needs no token (the gRPC health check)",
          len(health) == 1 and re.search(r'"health"', health[0]) is not None
          and '"meshes"' not in health[0], str(health))
    entry = [l for l in st["runtime"] if l.upper().startswith("ENTRYPOINT")]
    check("the image starts the daemon", len(entry) == 1 and '"serve"' in entry[0], str(entry))
    check("the image holds the installed layout",
          any(l.startswith("COPY --from=build /opt/geodesicd/") for l in st["runtime"]),
          "no COPY of the installed prefix")

    # The health subcommand the HEALTHCHECK runs exists and answers for a
    # server that is down with a failure, not a hang.
    r = subprocess.run([os.path.join(bin_dir, "geodesic"), "--server", "127.0.0.1:1",
                        "--timeout", "2", "health"], capture_output=True, text=True, timeout=30)
    check("geodesic health fails for a server that is down", r.returncode != 0,
          r.stdout + r.stderr)
    print(f"{len(failures)} failed")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
