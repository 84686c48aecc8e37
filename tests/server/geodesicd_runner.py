"""Runs the geodesicd binary for the offline commands' Python tests."""
import os
import subprocess
import sys


def geodesicd_runner(bin_dir):
    """run(*args, expect_ok=True) runs `geodesicd ARGS` and returns its
    CompletedProcess (text); with expect_ok a non-zero exit ends the test,
    naming the command and its stderr."""
    def run(*args, expect_ok=True):
        r = subprocess.run([os.path.join(bin_dir, "geodesicd"), *args], capture_output=True,
                           text=True, timeout=120)
        if expect_ok and r.returncode != 0:
            sys.exit(f"geodesicd {' '.join(args)} failed: {r.stderr}")
        return r
    return run


def read_obj(path):
    """Vertices (float64) and triangles (int32) of an OBJ (corners v, v/vt,
    v//vn, v/vt/vn)."""
    import numpy as np
    vertices, faces = [], []
    with open(path) as f:
        for line in f:
            fields = line.split()
            if fields and fields[0] == "v":
                vertices.append([float(x) for x in fields[1:4]])
            elif fields and fields[0] == "f":
                faces.append([int(c.split("/")[0]) - 1 for c in fields[1:]])
    return np.array(vertices), np.array(faces, dtype=np.int32)
