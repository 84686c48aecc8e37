#!/usr/bin/env python3
"""1-to-4 midpoint subdivision of a triangle mesh, for scale benchmarks.

Every triangle becomes four: a new vertex at the midpoint of each edge (one per
edge, shared by its faces), old vertices kept in place and order. V grows to
V + E (about 4x), F to 4F; the surface, and so every geodesic distance, stays
the same, which keeps results comparable with the mesh subdivided.

    subdivide_mesh.py IN.ply OUT.ply [--times K]

Reads binary little-endian PLY (float or double x y z; a uchar-counted list of
int or uint vertex indices, triangles only), writes the same format.
Needs numpy (Debian's python3-numpy: run with /usr/bin/python3).
"""
import argparse
import sys

import numpy as np

SCALARS = {"float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8",
           "int": "<i4", "int32": "<i4", "uint": "<u4", "uint32": "<u4",
           "uchar": "u1", "uint8": "u1"}


def read_ply(path):
    with open(path, "rb") as f:
        if f.readline().strip() != b"ply":
            sys.exit(f"{path}: not a PLY file")
        elements, current = [], None
        while True:
            line = f.readline()
            if not line:
                sys.exit(f"{path}: no end_header")
            words = line.decode("ascii").split()
            if not words or words[0] in ("comment", "obj_info"):
                continue
            if words[0] == "format" and words[1] != "binary_little_endian":
                sys.exit(f"{path}: format {words[1]}; only binary_little_endian is read")
            if words[0] == "element":
                current = (words[1], int(words[2]), [])
                elements.append(current)
            elif words[0] == "property":
                current[2].append(words[1:])
            elif words[0] == "end_header":
                break
        data = f.read()
    at, vertices, faces = 0, None, None
    for name, count, props in elements:
        if name == "vertex":
            if any(p[0] == "list" for p in props):
                sys.exit(f"{path}: list properties on vertices are not read")
            dtype = np.dtype([(p[1], SCALARS[p[0]]) for p in props])
            table = np.frombuffer(data, dtype, count, at)
            at += count * dtype.itemsize
            vertices = np.stack([table["x"], table["y"], table["z"]], axis=1).astype(np.float64)
        elif name == "face":
            if len(props) != 1 or props[0][0] != "list":
                sys.exit(f"{path}: faces must hold one index list only")
            dtype = np.dtype([("n", SCALARS[props[0][1]]), ("v", SCALARS[props[0][2]], 3)])
            table = np.frombuffer(data, dtype, count, at)
            if (table["n"] != 3).any():
                sys.exit(f"{path}: only triangles are read")
            at += count * dtype.itemsize
            faces = table["v"].astype(np.int64)
        else:
            sys.exit(f"{path}: element {name} is not read")
    return vertices, faces


def write_ply(path, vertices, faces):
    header = (f"ply\nformat binary_little_endian 1.0\n"
              f"comment made by geodesicd bench/subdivide_mesh.py\n"
              f"element vertex {len(vertices)}\n"
              "property float x\nproperty float y\nproperty float z\n"
              f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n")
    face_table = np.empty(len(faces), np.dtype([("n", "u1"), ("v", "<i4", 3)]))
    face_table["n"] = 3
    face_table["v"] = faces
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(vertices.astype("<f4").tobytes())
        f.write(face_table.tobytes())


def subdivide(vertices, faces):
    n = len(vertices)
    # The three edges of every face, as (min, max) pairs: face f's edge k is
    # row 3f + k, opposite corner k (from corner k+1 to k+2).
    a = faces[:, [1, 2, 0]].reshape(-1)
    b = faces[:, [2, 0, 1]].reshape(-1)
    pairs = np.stack([np.minimum(a, b), np.maximum(a, b)], axis=1)
    unique, inverse = np.unique(pairs, axis=0, return_inverse=True)
    midpoints = 0.5 * (vertices[unique[:, 0]] + vertices[unique[:, 1]])
    mid = (n + inverse.reshape(-1)).reshape(-1, 3)  # mid[f, k]: midpoint opposite corner k
    v0, v1, v2 = faces[:, 0], faces[:, 1], faces[:, 2]
    m0, m1, m2 = mid[:, 0], mid[:, 1], mid[:, 2]
    new_faces = np.concatenate([
        np.stack([v0, m2, m1], axis=1),
        np.stack([v1, m0, m2], axis=1),
        np.stack([v2, m1, m0], axis=1),
        np.stack([m0, m1, m2], axis=1),
    ])
    return np.concatenate([vertices, midpoints]), new_faces


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("input")
    parser.add_argument("output")
    parser.add_argument("--times", type=int, default=1, help="subdivision steps (default 1)")
    args = parser.parse_args()
    vertices, faces = read_ply(args.input)
    for _ in range(args.times):
        vertices, faces = subdivide(vertices, faces)
    write_ply(args.output, vertices, faces)
    print(f"{args.output}: {len(vertices)} vertices, {len(faces)} faces")


if __name__ == "__main__":
    main()
