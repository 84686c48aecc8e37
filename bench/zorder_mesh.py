#!/usr/bin/python3
"""Renumbers a triangle mesh's vertices and faces in Morton (Z) order.

Measures what memory locality of the mesh is worth to the exact engine: the
same surface, the same per-face vertex order, only the ids change. A pairs
file (`geodesicd distance --pairs`) of face and vertex points is carried over
to the new ids so that both meshes answer the same queries.

Usage: bench/zorder_mesh.py IN.obj OUT.obj [PAIRS_IN PAIRS_OUT]
"""
import sys

import numpy as np


def read_obj(path):
    vertices, faces = [], []
    for line in open(path):
        if line.startswith("v "):
            vertices.append([float(x) for x in line.split()[1:4]])
        elif line.startswith("f "):
            corners = line.split()[1:]
            if len(corners) != 3:
                sys.exit(f"{path}: face {len(faces)} has {len(corners)} corners, not 3")
            faces.append([int(c.split("/")[0]) - 1 for c in corners])
    return np.array(vertices), np.array(faces)


def morton_order(points, bits=10):
    """Indices that sort `points` along a Z-order curve of 2^bits cells a side."""
    lo = points.min(axis=0)
    scale = (2**bits - 1) / max((points.max(axis=0) - lo).max(), 1e-300)
    cells = ((points - lo) * scale).astype(np.uint64)
    code = np.zeros(len(points), dtype=np.uint64)
    for bit in range(bits):
        for axis in range(3):
            code |= ((cells[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    return np.argsort(code, kind="stable")


def inverse(order):
    new_id = np.empty_like(order)
    new_id[order] = np.arange(len(order))
    return new_id


def main():
    if len(sys.argv) not in (3, 5):
        sys.exit(__doc__)
    vertices, faces = read_obj(sys.argv[1])
    vertex_order = morton_order(vertices)
    face_order = morton_order(vertices[faces].mean(axis=1))
    new_vertex, new_face = inverse(vertex_order), inverse(face_order)
    with open(sys.argv[2], "w") as out:
        for p in vertices[vertex_order]:
            out.write("v %.17g %.17g %.17g\n" % tuple(p))
        for f in faces[face_order]:
            out.write("f %d %d %d\n" % tuple(new_vertex[f] + 1))
    if len(sys.argv) == 5:
        renumber = {"f": new_face, "v": new_vertex}
        with open(sys.argv[4], "w") as out:
            for line in open(sys.argv[3]):
                points = []
                for token in line.split():
                    kind, index, *rest = token.split(":", 2)
                    if kind not in renumber:
                        sys.exit(f"{sys.argv[3]}: cannot renumber {token} (edge ids depend on the "
                                 "half-edge structure)")
                    points.append(":".join([kind, str(renumber[kind][int(index)])] + rest))
                if points:
                    out.write(" ".join(points) + "\n")


if __name__ == "__main__":
    main()
