#!/usr/bin/env python3
"""The code keeps the shape a newcomer relies on.

- core/ is in folders by the paper's stages, each including only itself and
  the folders below it: base < mesh < exact < dgg < query. A file directly in
  core/ (other than CMakeLists.txt) is refused: it would belong to no stage.
- core/ includes nothing from server/, client/, proto/ or gRPC.
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
    sizes, functions = long_functions(root)
    for problem in layering + sizes:
        print("FAIL", problem)
    print(f"{files} core files checked for layering, {functions} functions measured")
    return 1 if layering or sizes else 0


if __name__ == "__main__":
    sys.exit(main())
