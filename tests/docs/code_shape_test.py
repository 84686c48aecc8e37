#!/usr/bin/env python3
"""The code keeps the shape a newcomer relies on.

- core/ is in folders by the paper's stages, each including only itself and
  the folders below it: base < mesh < exact < dgg < query. A file directly in
  core/ (other than CMakeLists.txt) is refused: it would belong to no stage.
- core/ includes nothing from server/, client/, proto/ or gRPC.
- server/ is in folders by concern, each including only itself and the folders
  below it: base < http < offline < limits < store < meshes < graphs < api <
  grpc < gateway < app. Nothing but CMakeLists.txt and folders sits directly
  in server/, no header includes, through any chain, itself, and no file is
  longer than MAX_SERVER_FILE_LINES.
- No function outside tests is longer than MAX_FUNCTION_LINES, measured by
  universal-ctags (its end line minus its start line, plus one).

Usage: code_shape_test.py SOURCE_DIR
"""
import os
import re
import shutil
import subprocess
import sys

STAGES = ["base", "mesh", "exact", "dgg", "query"]
# server/'s folders by concern, lowest first (server/CMakeLists.txt names
# what each holds); web/ holds the gateway's static files, no source.
SERVER_RANKS = ["base", "http", "offline", "limits", "store", "meshes", "graphs", "api", "grpc",
                "gateway", "app"]
SERVER_ASSETS = ["web"]
# A file a newcomer reads whole: past this it holds more than one concern.
MAX_SERVER_FILE_LINES = 800
MAX_FUNCTION_LINES = 100
# Where functions are measured: everything that ships or measures, not tests
# and not generated code.
MEASURED_DIRS = ["core", "server", "client", "bench", "scripts", "deploy"]
SKIPPED_PARTS = {"build", "_proto", "__pycache__", "venv", "node_modules"}
INCLUDE = re.compile(r'^\s*#\s*include\s+["<]([^">]+)[">]', re.M)


def source_files(root, top, suffixes):
    for dirpath, dirnames, filenames in os.walk(os.path.join(root, top)):
        dirnames[:] = [d for d in dirnames if d not in SKIPPED_PARTS and not d.startswith("build")]
        for name in filenames:
            if name.endswith(suffixes):
                yield os.path.join(dirpath, name)


def layering_problems(root):
    problems = []
    core = os.path.join(root, "core")
    for name in os.listdir(core):
        if os.path.isfile(os.path.join(core, name)) and name != "CMakeLists.txt":
            problems.append(f"core/{name} is in no stage folder ({', '.join(STAGES)})")
    checked = 0
    for path in source_files(root, "core", (".h", ".cc", ".h.in")):
        rel = os.path.relpath(path, root)
        parts = rel.split(os.sep)
        if len(parts) < 3 or parts[1] not in STAGES:
            problems.append(f"{rel} is in no stage folder ({', '.join(STAGES)})")
            continue
        rank = STAGES.index(parts[1])
        checked += 1
        with open(path, encoding="utf-8") as f:
            text = f.read()
        for included in INCLUDE.findall(text):
            if included.startswith(("server/", "client/", "proto/", "grpc")) or "grpc" in included:
                problems.append(f"{rel} includes {included}: core must not depend on the server")
            if included.startswith("core/"):
                stage = included.split("/")[1]
                if stage not in STAGES:
                    problems.append(f"{rel} includes {included}, which is in no stage folder")
                elif STAGES.index(stage) > rank:
                    problems.append(
                        f"{rel} ({parts[1]}) includes {included} ({stage}), a stage above it")
    if checked == 0:
        problems.append("no source file found under core/")
    return problems, checked


def server_problems(root):
    """Folder ranks and include cycles of server/: (problems, files checked)."""
    problems, includes = [], {}
    server = os.path.join(root, "server")
    for name in sorted(os.listdir(server)):
        path = os.path.join(server, name)
        if os.path.isfile(path) and name != "CMakeLists.txt":
            problems.append(f"server/{name} is in no folder ({', '.join(SERVER_RANKS)})")
        elif os.path.isdir(path) and name not in SERVER_RANKS + SERVER_ASSETS:
            problems.append(f"server/{name}/ is not a known folder ({', '.join(SERVER_RANKS)})")
    for path in source_files(root, "server", (".h", ".cc")):
        rel = os.path.relpath(path, root)
        folder = rel.split(os.sep)[1]
        if folder not in SERVER_RANKS:
            continue
        with open(path, encoding="utf-8") as f:
            text = f.read()
        lines = text.count("\n")
        if lines > MAX_SERVER_FILE_LINES:
            problems.append(f"{rel} is {lines} lines (at most {MAX_SERVER_FILE_LINES})")
        included = [i for i in INCLUDE.findall(text) if i.startswith("server/")]
        includes[rel] = included
        for i in included:
            other = i.split("/")[1]
            if other not in SERVER_RANKS:
                problems.append(f"{rel} includes {i}, which is in no folder")
            elif SERVER_RANKS.index(other) > SERVER_RANKS.index(folder):
                problems.append(f"{rel} ({folder}) includes {i} ({other}), a folder above it")
    # A cycle of includes, inside one folder or across: depth-first from each
    # header, the path so far on a stack.
    def visit(node, stack, done):
        if node in stack:
            cycle = stack[stack.index(node):] + [node]
            problems.append("include cycle: " + " -> ".join(cycle))
            return
        if node in done:
            return
        done.add(node)
        for nxt in includes.get(node, []):
            visit(nxt, stack + [node], done)
    done = set()
    for node in sorted(includes):
        visit(node, [], done)
    if not includes:
        problems.append("no source file found under server/")
    return problems, len(includes)


def long_functions(root):
    ctags = shutil.which("ctags")
    if ctags is None:
        return ["universal-ctags is not installed (scripts/setup.sh installs it)"], 0
    files = []
    for top in MEASURED_DIRS:
        files += source_files(root, top, (".cc", ".h", ".py"))
    out = subprocess.run(
        [ctags, "--languages=C++,Python", "--kinds-C++=f", "--kinds-Python=fm",
         "--fields=+ne", "-x", "--_xformat=%{line} %{end} %{input} %{name}"] + files,
        check=True, capture_output=True, text=True).stdout
    problems = []
    measured = 0
    for line in out.splitlines():
        start, end, path, name = line.split(" ", 3)
        if not start.isdigit() or not end.isdigit():
            continue
        measured += 1
        length = int(end) - int(start) + 1
        if length > MAX_FUNCTION_LINES:
            rel = os.path.relpath(path, root)
            problems.append(f"{rel}:{start} {name} is {length} lines (at most {MAX_FUNCTION_LINES})")
    if measured == 0:
        problems.append("ctags measured no function: the measurement itself is broken")
    return problems, measured


def main():
    root = sys.argv[1]
    layering, files = layering_problems(root)
    server, server_files = server_problems(root)
    sizes, functions = long_functions(root)
    for problem in layering + server + sizes:
        print("FAIL", problem)
    print(f"{files} core files and {server_files} server files checked for layering, "
          f"{functions} functions measured")
    return 1 if layering or server or sizes else 0


if __name__ == "__main__":
    sys.exit(main())
