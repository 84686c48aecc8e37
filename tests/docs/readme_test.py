#!/usr/bin/env python3
"""The README runs as written.

Runs every ```sh and ```python block of README.md in order, the quick start
aside (it installs packages and builds; CI runs it as .ci/run), in a
temporary directory holding a link to the repository's data/ and with the
build's binaries first on PATH, as scripts/quickstart.sh leaves them. Blocks
fenced as ```sh norun (or ```text) are shown to the reader only.

What a test may not do as written is rewritten, and only that:
- a daemon the README starts (`geodesicd serve ... &`) listens on ports the
  system picks (`--listen`/`--http-listen`/`--metrics-listen` at port 0, a
  --port-file read back) and writes its graphs to a temporary directory;
  later blocks' 127.0.0.1:50051 / :8080 / :9090 are that daemon's ports;
- paths under /var/lib/geodesicd become the temporary directory.
The temporary directory links the repository's data/, client/ and proto/,
which the README names by relative path; once a block has made venv/, the
Python blocks run on it.
The daemon is stopped at the end. A block that exits non-zero fails the test,
naming the block's first line.

Usage: readme_test.py BUILD_BIN_DIR SOURCE_DIR
"""
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "server"))
import daemon_ports  # noqa: E402

BIN, SRC = os.path.abspath(sys.argv[1]), os.path.abspath(sys.argv[2])
DEFAULT_PORTS = {"grpc": "50051", "http": "8080", "metrics": "9090"}


def blocks(readme):
    """(language, first line number, text) of each runnable fenced block."""
    out, lang, start, lines, section = [], None, 0, [], ""
    for number, line in enumerate(open(readme).read().splitlines(), 1):
        if lang is None:
            if line.startswith("## "):
                section = line[3:].strip().lower()
            m = re.match(r"^```(\w+)?\s*(\w+)?\s*$", line)
            if m:
                lang, start, lines = (m.group(1) or "text", m.group(2) or ""), number + 1, []
        elif line.startswith("```"):
            language, flag = lang
            if language in ("sh", "python") and flag != "norun" and \
                    not section.startswith("quick start"):
                out.append((language, start, "\n".join(lines)))
            lang = None
        else:
            lines.append(line)
    return out


class Runner:
    def __init__(self, work):
        self.work = work
        self.ports = {}
        self.daemon = None
        self.starts = 0
        self.env = dict(os.environ)
        # Debian's own python3 and tools first, as on the machine the README is for.
        self.env["PATH"] = os.pathsep.join([BIN, "/usr/bin", self.env.get("PATH", "")])
        self.env["PYTHONPATH"] = os.path.join(SRC, "client", "python")
        self.env["HOME"] = os.path.join(work, "home")
        os.makedirs(self.env["HOME"], exist_ok=True)

    def rewrite(self, text):
        text = text.replace("/var/lib/geodesicd", os.path.join(self.work, "var"))
        for name, port in self.ports.items():
            text = text.replace(f"127.0.0.1:{DEFAULT_PORTS[name]}", f"127.0.0.1:{port}")
            text = text.replace(f"localhost:{DEFAULT_PORTS[name]}", f"127.0.0.1:{port}")
        return text

    def start_daemon(self, line):
        """Runs a `geodesicd serve ... &` line on free ports, in the background."""
        self.starts += 1
        # One file per start: a second daemon's ports are never the first's.
        port_file = os.path.join(self.work, f"ports.{self.starts}.json")
        command = line.rstrip().rstrip("&").strip()
        for flag in ("--listen", "--http-listen", "--metrics-listen"):
            command = re.sub(rf"{flag}[ =]\S+", f"{flag} 127.0.0.1:0", command)
        command = re.sub(r"--port-file[ =]\S+", "", command)
        command += f" --port-file {port_file}"
        if "--listen" not in command:
            command += " --listen 127.0.0.1:0"
        log = open(os.path.join(self.work, "daemon.log"), "w")
        self.daemon = subprocess.Popen(["bash", "-c", "exec " + command], cwd=self.work,
                                       env=self.env, stdout=log, stderr=subprocess.STDOUT,
                                       start_new_session=True)
        daemon_ports.watch(self.daemon)
        ports = daemon_ports.wait_for_ports(self.daemon, port_file, 60, log.name)
        self.ports = {k: str(v) for k, v in ports.items()}
        # The CLI and the Python client default to $GEODESIC_SERVER.
        self.env["GEODESIC_SERVER"] = f"127.0.0.1:{self.ports['grpc']}"
        print(f"     daemon on {self.ports}", flush=True)

    def run(self, language, start, text):
        text = self.rewrite(text)
        if language == "sh":
            kept = []
            for line in re.sub(r"\\\n\s*", " ", text).splitlines():
                if re.match(r"^\s*geodesicd serve\b.*&\s*$", line):
                    self.start_daemon(line)
                    kept.append("# (daemon started by the test)")
                else:
                    kept.append(line)
            argv = ["bash", "-euo", "pipefail", "-c", self.rewrite("\n".join(kept))]
        else:
            argv = [sys.executable, "-c", text]
        env = dict(self.env)
        venv_python = os.path.join(self.work, "venv", "bin", "python")
        if language == "python" and os.path.exists(venv_python):
            # The README installed the package: run its examples on that.
            argv[0] = venv_python
            env.pop("PYTHONPATH", None)
        r = subprocess.run(argv, cwd=self.work, env=env, capture_output=True, text=True,
                           timeout=600)
        first = text.strip().splitlines()[0] if text.strip() else ""
        if r.returncode != 0:
            print(f"FAIL README line {start} ({language}: {first!r}): exit {r.returncode}\n"
                  f"--- stdout\n{r.stdout[-3000:]}\n--- stderr\n{r.stderr[-3000:]}", flush=True)
            return False
        print(f"ok   README line {start} ({language}: {first!r})", flush=True)
        return True

    def stop(self):
        if self.daemon and self.daemon.poll() is None:
            os.killpg(self.daemon.pid, signal.SIGTERM)
            try:
                self.daemon.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(self.daemon.pid, signal.SIGKILL)


def main():
    found = blocks(os.path.join(SRC, "README.md"))
    if len(found) < 5:
        print(f"FAIL: only {len(found)} runnable blocks in README.md")
        return 1
    work = tempfile.mkdtemp(prefix="geodesic-readme-")
    # The repository's files the README names by relative path.
    for name in ("data", "client", "proto"):
        os.symlink(os.path.join(SRC, name), os.path.join(work, name))
    runner = Runner(work)
    passed = failed = 0
    try:
        for language, start, text in found:
            if not runner.run(language, start, text):
                failed += 1
                break  # later blocks build on earlier ones
            passed += 1
    finally:
        runner.stop()
        if failed and os.path.exists(os.path.join(work, "daemon.log")):
            print("--- daemon log (tail)\n" + open(os.path.join(work, "daemon.log")).read()[-3000:])
        shutil.rmtree(work, ignore_errors=True)
    print(f"README blocks: {passed} of {len(found)} ran, {failed} failed")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
