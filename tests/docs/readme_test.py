#!/usr/bin/env python3
"""The README and the pages under docs/ run as written.

Runs every ```sh, ```python and ```js block of one page (README.md unless
PAGE, a path under SOURCE_DIR such as docs/daemon.md, is given) in order,
README's quick start aside (it installs packages and builds; CI runs it as .ci/run),
in a fresh temporary directory holding a link to the repository's data/ and
with the build's binaries first on PATH, as scripts/quickstart.sh leaves
them. Each page is a test of its own and runs alone: a page whose blocks need
a daemon starts it in its own blocks. Blocks fenced as ```sh norun (or
```text) are shown to the reader only. Before its blocks run, the page's
relative links must point to existing files (and headings, for #anchors).

What a test may not do as written is rewritten, and only that:
- a daemon a page starts (`geodesicd serve ... &`) listens on ports the
  system picks (`--listen`/`--http-listen`/`--metrics-listen` at port 0, a
  --port-file read back) and writes its graphs to a temporary directory;
  later blocks' 127.0.0.1:50051 / :8080 / :9090 are that daemon's ports;
- paths under /var/lib/geodesicd become the temporary directory.
The temporary directory links the repository's data/, client/ and proto/,
which the pages name by relative path; once a block has made venv/, the
Python blocks run on it. A ```js block runs as an ES module (`node
--input-type=module`), importing "geodesic-client" from client/node as
scripts/setup.sh built it (node_modules/ there links it).
Every daemon is stopped at the end. A block that exits non-zero fails the
test, naming the page, the block's line and its first line.

With --links, runs no block: checks the relative links of README.md and of
every docs/*.md, that README.md links to every page under docs/, and that
every page there with runnable blocks is registered as a test of its own
(tests/CMakeLists.txt).

Usage: readme_test.py BUILD_BIN_DIR SOURCE_DIR [PAGE]
       readme_test.py --links SOURCE_DIR
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

BIN = SRC = ""  # set by main()
DEFAULT_PORTS = {"grpc": "50051", "http": "8080", "metrics": "9090"}


def blocks(page):
    """(language, first line number, text) of each runnable fenced block."""
    out, lang, start, lines, section = [], None, 0, [], ""
    for number, line in enumerate(open(page).read().splitlines(), 1):
        if lang is None:
            if line.startswith("## "):
                section = line[3:].strip().lower()
            m = re.match(r"^```(\w+)?\s*(\w+)?\s*$", line)
            if m:
                lang, start, lines = (m.group(1) or "text", m.group(2) or ""), number + 1, []
        elif line.startswith("```"):
            language, flag = lang
            if language in ("sh", "python", "js") and flag != "norun" and \
                    not section.startswith("quick start"):
                out.append((language, start, "\n".join(lines)))
            lang = None
        else:
            lines.append(line)
    return out


def prose(page):
    """(line number, line) of the page outside fenced blocks, inline code cut out."""
    fenced = False
    for number, line in enumerate(open(page).read().splitlines(), 1):
        if line.startswith("```"):
            fenced = not fenced
        elif not fenced:
            yield number, re.sub(r"`[^`]*`", "", line)


def anchors(page):
    """The #anchors of a page's headings, as GitHub makes them."""
    out = set()
    for _, line in prose(page):
        m = re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
        if m:
            out.add(re.sub(r"[^\w\- ]", "", m.group(1).lower()).replace(" ", "-"))
    return out


def link_problems(src, name):
    """Relative links of src/name that point to no file, or to no heading there."""
    page = os.path.join(src, name)
    problems = []
    for number, line in prose(page):
        for target in re.findall(r"\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)", line):
            if re.match(r"^[a-z][a-z0-9+.-]*:", target):
                continue  # http:, https:, mailto:
            path, _, anchor = target.partition("#")
            file = os.path.normpath(os.path.join(os.path.dirname(page), path)) if path else page
            if not os.path.exists(file):
                problems.append(f"{name}:{number}: link to {target}: no such file")
            elif anchor and file.endswith(".md") and anchor not in anchors(file):
                problems.append(f"{name}:{number}: link to {target}: no such heading")
    return problems


def check_links(src):
    """--links: every page's relative links, and README linking every page under docs/."""
    pages = ["README.md"] + sorted(os.path.join("docs", f) for f in os.listdir(
        os.path.join(src, "docs")) if f.endswith(".md"))
    problems = [p for name in pages for p in link_problems(src, name)]
    readme = open(os.path.join(src, "README.md")).read()
    cmake = open(os.path.join(src, "tests", "CMakeLists.txt")).read()
    registered = re.search(r"foreach\(page ([^)]*)\)", cmake)
    registered = registered.group(1).split() if registered else []
    for name in pages[1:]:
        if f"]({name}" not in readme:
            problems.append(f"README.md does not link to {name}")
        stem = os.path.basename(name)[:-3]
        if blocks(os.path.join(src, name)) and stem not in registered:
            problems.append(f"{name} has runnable blocks but no docs_{stem} test "
                            "(tests/CMakeLists.txt, foreach(page ...))")
    for problem in problems:
        print("FAIL " + problem)
    print(f"links: {len(pages)} pages, {len(problems)} problems")
    return 1 if problems else 0


class Runner:
    def __init__(self, work, page):
        self.work = work
        self.page = page
        self.ports = {}
        self.daemons = []
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
        log = open(os.path.join(self.work, "daemon.log"), "a")
        daemon = subprocess.Popen(["bash", "-c", "exec " + command], cwd=self.work,
                                  env=self.env, stdout=log, stderr=subprocess.STDOUT,
                                  start_new_session=True)
        self.daemons.append(daemon)
        daemon_ports.watch(daemon)
        ports = daemon_ports.wait_for_ports(daemon, port_file, 60, log.name)
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
        elif language == "js":
            argv = ["node", "--input-type=module", "-e", text]
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
            print(f"FAIL {self.page} line {start} ({language}: {first!r}): exit {r.returncode}\n"
                  f"--- stdout\n{r.stdout[-3000:]}\n--- stderr\n{r.stderr[-3000:]}", flush=True)
            return False
        print(f"ok   {self.page} line {start} ({language}: {first!r})", flush=True)
        return True

    def stop(self):
        for daemon in self.daemons:
            if daemon.poll() is None:
                os.killpg(daemon.pid, signal.SIGTERM)
        for daemon in self.daemons:
            try:
                daemon.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(daemon.pid, signal.SIGKILL)


def main():
    if sys.argv[1] == "--links":
        return check_links(os.path.abspath(sys.argv[2]))
    global BIN, SRC
    BIN, SRC = os.path.abspath(sys.argv[1]), os.path.abspath(sys.argv[2])
    page = sys.argv[3] if len(sys.argv) > 3 else "README.md"
    problems = link_problems(SRC, page)
    back = os.path.relpath(os.path.join(SRC, "README.md"),
                           os.path.dirname(os.path.join(SRC, page)))
    if page != "README.md" and f"]({back})" not in open(os.path.join(SRC, page)).read():
        problems.append(f"{page} does not link back to {back}")
    for problem in problems:
        print("FAIL " + problem)
    found = blocks(os.path.join(SRC, page))
    if not found:
        print(f"FAIL: no runnable block in {page}")
        return 1
    if problems:
        return 1
    work = tempfile.mkdtemp(prefix="geodesic-docs-")
    # The repository's files the pages name by relative path.
    for name in ("data", "client", "proto"):
        os.symlink(os.path.join(SRC, name), os.path.join(work, name))
    os.makedirs(os.path.join(work, "node_modules"))
    os.symlink(os.path.join(SRC, "client", "node"),
               os.path.join(work, "node_modules", "geodesic-client"))
    runner = Runner(work, page)
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
    print(f"{page} blocks: {passed} of {len(found)} ran, {failed} failed")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
