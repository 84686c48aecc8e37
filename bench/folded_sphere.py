#!/usr/bin/python3
"""A folded sphere shaped like a cortical hemisphere, as a GIFTI surface.

Neuroimaging pipelines ask for matrices on cortical surfaces: closed,
regular triangulations folded into gyri and sulci. None of the shared scans
is one, so this makes a stand-in: a geodesic icosphere (each face of the
icosahedron cut into F^2 triangles, 10 F^2 + 2 vertices), pushed in and out
along its normals by a sum of plane waves in random directions (seeded, so
the same arguments give the same file), then stretched to a hemisphere's
size in millimetres.

    folded_sphere.py OUT.surf.gii [--frequency 39] [--depth 0.25] [--seed 7]

Frequency 39 gives 15,212 vertices. The pointset carries the
AnatomicalStructurePrimary that Workbench copies into its CIFTI output.
Needs numpy and nibabel (Debian's python3-nibabel: run with /usr/bin/python3).
"""
import argparse

import numpy as np
import nibabel as nib

GOLDEN = (1 + 5 ** 0.5) / 2
ICOSAHEDRON_VERTICES = np.array(
    [[-1, GOLDEN, 0], [1, GOLDEN, 0], [-1, -GOLDEN, 0], [1, -GOLDEN, 0],
     [0, -1, GOLDEN], [0, 1, GOLDEN], [0, -1, -GOLDEN], [0, 1, -GOLDEN],
     [GOLDEN, 0, -1], [GOLDEN, 0, 1], [-GOLDEN, 0, -1], [-GOLDEN, 0, 1]], dtype=float)
ICOSAHEDRON_FACES = [
    [0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
    [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
    [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]]
HEMISPHERE_MM = np.array([70.0, 90.0, 60.0])


def icosphere(frequency: int):
    """Unit-sphere vertices and triangles of the geodesic icosphere."""
    index, points, triangles = {}, [], []

    def vertex(p):
        p = p / np.linalg.norm(p)
        # Points on a shared icosahedron edge come out of both faces: merge
        # them by their rounded position.
        key = tuple(np.round(p, 9))
        if key not in index:
            index[key] = len(points)
            points.append(p)
        return index[key]

    for a, b, c in ICOSAHEDRON_FACES:
        A, B, C = ICOSAHEDRON_VERTICES[[a, b, c]]
        grid = {(i, j): vertex(A + (B - A) * i / frequency + (C - A) * j / frequency)
                for i in range(frequency + 1) for j in range(frequency + 1 - i)}
        for i in range(frequency):
            for j in range(frequency - i):
                triangles.append([grid[i, j], grid[i + 1, j], grid[i, j + 1]])
                if i + j + 1 < frequency:
                    triangles.append([grid[i + 1, j], grid[i + 1, j + 1], grid[i, j + 1]])
    return np.array(points), np.array(triangles, dtype=np.int32)


def fold(points: np.ndarray, depth: float, seed: int, waves: int = 14) -> np.ndarray:
    """Points moved along their normals by plane waves of random direction."""
    rng = np.random.default_rng(seed)
    radius = np.ones(len(points))
    for _ in range(waves):
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        radius += depth / 3 * np.sin(rng.uniform(8, 14) * points @ direction
                                     + rng.uniform(0, 2 * np.pi))
    return points * radius[:, None] * HEMISPHERE_MM


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out")
    ap.add_argument("--frequency", type=int, default=39)
    ap.add_argument("--depth", type=float, default=0.25)
    ap.add_argument("--seed", type=int, default=7)
    args = ap.parse_args()
    points, triangles = icosphere(args.frequency)
    points = fold(points, args.depth, args.seed)
    image = nib.gifti.GiftiImage()
    meta = nib.gifti.GiftiMetaData({"AnatomicalStructurePrimary": "CortexLeft"})
    image.add_gifti_data_array(nib.gifti.GiftiDataArray(
        points.astype(np.float32), intent="NIFTI_INTENT_POINTSET",
        datatype="NIFTI_TYPE_FLOAT32", meta=meta))
    image.add_gifti_data_array(nib.gifti.GiftiDataArray(
        triangles, intent="NIFTI_INTENT_TRIANGLE", datatype="NIFTI_TYPE_INT32"))
    nib.save(image, args.out)
    print(f"{args.out}: {len(points)} vertices, {len(triangles)} triangles")


if __name__ == "__main__":
    main()
