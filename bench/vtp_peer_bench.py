#!/usr/bin/env python3
"""Our exact field beside VTP's (Qin et al., SIGGRAPH 2016, the authors' public
code) in the same run: one whole field from vertex 0 per mesh, the two
programs alternating on one pinned CPU, a few rounds each, and the two fields
compared value by value.

  bench/vtp_peer_bench.py --vtp VTP_BINARY [--geodesicd build/bin/geodesicd]
      [--meshes eight,spot,...] [--rounds 3] [--cpu 1]

VTP is not part of this project and is not vendored: build it yourself from
github.com/YipengQin/VTP_source_code. Its code is written for MSVC; with g++
on Debian 12 it needs strcpy_s and sscanf_s replaced by strcpy and sscanf,
std::auto_ptr by std::unique_ptr, and <memory> and <cstring> included in
stdafx.h; then `g++ -O3 -march=native -DNDEBUG -std=c++11 main.cpp -o vtp`.

VTP reads OBJ only, so each mesh is written as OBJ first (coordinates printed
exactly). VTP merges coincident vertices; a mesh where that changes the
vertex count is reported and skipped, since vertex 0 would differ.

Prints a Markdown table for bench/measurements.md: median propagation seconds
of each (VTP's own clock around its propagation; our solve_seconds), their
ratio, children computed (a window propagated across a face, counted before
any trim: VTP's "interval propagation number" and our children_computed, the
same count), our windows queued after the trims, and the largest relative
difference between the two fields (and, where ../shared/truth has the field
from vertex 0, between ours and that exact truth).

Our build uses the project's flags (-O3, no -march=native). For a same-flags
comparison build VTP with `g++ -O3 -DNDEBUG -std=c++11` as well; -march=native
speeds VTP up more than it does ours (bench/measurements.md, "Exact engine
beside VTP: same flags, children computed").
"""
import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile

import numpy as np

from exact_ab_bench import MESHES, SHARED, largest_difference, mesh_file, solve
from subdivide_mesh import read_ply

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def read_off(path):
    with open(path) as f:
        words = [w for line in f for w in line.split("#", 1)[0].split()]
    if not words or not words[0].endswith("OFF"):
        sys.exit(f"{path}: not an OFF file")
    nv, nf = int(words[1]), int(words[2])
    at = 4
    vertices = np.array(words[at:at + 3 * nv], dtype=np.float64).reshape(nv, 3)
    at += 3 * nv
    faces = []
    for _ in range(nf):
        n = int(words[at])
        if n != 3:
            sys.exit(f"{path}: only triangles are read")
        faces.append([int(w) for w in words[at + 1:at + 4]])
        at += 1 + n
    return vertices, np.array(faces, dtype=np.int64)


def as_obj(mesh, work):
    """The mesh as an OBJ file VTP reads: v and f lines only."""
    if mesh.endswith(".obj"):
        return mesh
    vertices, faces = read_ply(mesh) if mesh.endswith(".ply") else read_off(mesh)
    out = os.path.join(work, os.path.splitext(os.path.basename(mesh))[0] + ".obj")
    with open(out, "w") as f:
        for x, y, z in vertices:
            f.write(f"v {x!r} {y!r} {z!r}\n")
        for a, b, c in faces + 1:
            f.write(f"f {a} {b} {c}\n")
    return out


def run_vtp(vtp, obj, cpu, out):
    result = subprocess.run(["taskset", "-c", str(cpu), vtp, "-m", obj, "-s", "0", "-o", out],
                            capture_output=True, text=True)
    if result.returncode != 0:
        sys.exit(f"{vtp} on {obj} failed:\n{result.stdout[-2000:]}{result.stderr[-2000:]}")
    seconds = re.search(r"propagation step took ([0-9.e+-]+) seconds", result.stdout)
    windows = re.search(r"total interval propagation number (\d+)", result.stdout)
    vertices = re.search(r"There are (\d+) non-coincidence vertices", result.stdout)
    if not (seconds and windows and vertices):
        sys.exit(f"{vtp}: unexpected output:\n{result.stdout[-2000:]}")
    return float(seconds.group(1)), int(windows.group(1)), int(vertices.group(1))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--vtp", required=True)
    parser.add_argument("--geodesicd", default=os.path.join(ROOT, "build", "bin", "geodesicd"))
    parser.add_argument("--meshes", default=",".join(MESHES))
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--cpu", type=int, default=1)
    args = parser.parse_args()
    print("| mesh | V | ours (s) | VTP (s) | ours / VTP | children ours | children VTP "
          "| children ours / VTP | windows queued ours | ours vs VTP, max rel. diff "
          "| ours vs truth |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as work:
        for name in args.meshes.split(","):
            mesh = mesh_file(name)
            obj = as_obj(mesh, work)
            ours, theirs = [], []
            for _ in range(args.rounds):
                ours.append(solve(args.geodesicd, mesh, args.cpu, f"{work}/ours.f64"))
                theirs.append(run_vtp(args.vtp, obj, args.cpu, f"{work}/vtp.txt"))
            if theirs[0][2] != ours[0]["vertices"]:
                print(f"| {name} | {ours[0]['vertices']:,} | VTP merged coincident vertices "
                      f"({theirs[0][2]:,} left): not compared | | | | | | | | |", flush=True)
                continue
            field = np.fromfile(f"{work}/ours.f64")
            vtp_field = np.loadtxt(f"{work}/vtp.txt")
            vtp_field[vtp_field >= 1e99] = np.inf  # VTP's "unreached" (vertices in no face)
            if field.size == 0 or vtp_field.size != field.size:
                sys.exit(f"{name}: fields of {field.size} and {vtp_field.size} values")
            diff = largest_difference(vtp_field, field)
            truth_file = os.path.join(SHARED, "truth", f"{name}.exact.s0.f64")
            truth = (f"{largest_difference(np.fromfile(truth_file), field):.2g}"
                     if os.path.exists(truth_file) else "-")
            t_ours = statistics.median(r["solve_seconds"] for r in ours)
            t_vtp = statistics.median(r[0] for r in theirs)
            c_ours, c_vtp = ours[0]["children_computed"], theirs[0][1]
            print(f"| {name} | {ours[0]['vertices']:,} | {t_ours:.3g} | {t_vtp:.3g} | "
                  f"{t_ours / t_vtp:.2f}x | {c_ours:,} | {c_vtp:,} | {c_ours / c_vtp:.2f}x | "
                  f"{ours[0]['windows_created']:,} | {diff:.2g} | {truth} |", flush=True)


if __name__ == "__main__":
    main()
