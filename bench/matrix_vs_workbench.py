#!/usr/bin/python3
"""All-pairs geodesic distance matrices: geodesicd against Connectome Workbench.

Runs, in one process tree and one after the other on the same surface:
  geodesicd build   SURFACE --eps EPS
  geodesicd matrix  --sources all --targets all --dtype float32 --threads T
  geodesicd build   SURFACE --eps EPS --exact-fans, and the same matrix on it
  wb_command -surface-geodesic-distance-all-to-all SURFACE OUT.dconn.nii
and prints a Markdown table (wall and CPU seconds, peak RSS, error against
exact fields) with the time ratios of the same run. The exact fields are
../shared/truth's where it has the surface's, else four from geodesicd's
own exact engine (`geodesicd exact`, from seeded random vertices).
Exact fans give the same distances (the two matrices are checked equal)
from smaller fans, for a longer build.
The surface is a GIFTI .surf.gii (what Workbench reads); an .off or .obj is
converted to one first (with nibabel), and a .surf.gii whose pointset names
no anatomical structure is copied with one (bench/folded_sphere.py makes a
cortex-like surface). wb_command is Debian's
connectome-workbench; without it only geodesicd's side is measured.

  bench/matrix_vs_workbench.py MESH [--eps 1e-3] [--threads 2] [--geodesicd PATH]
"""
import argparse
import json
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def read_off_or_obj(path: Path):
    """Vertices (N x 3 float64) and triangles (M x 3 int32) of a plain OFF/OBJ."""
    text = path.read_text().split("\n")
    if path.suffix.lower() == ".off":
        words = " ".join(l.split("#")[0] for l in text).split()
        assert words[0].upper() == "OFF", f"{path}: not an OFF file"
        nv, nf = int(words[1]), int(words[2])
        v = np.array(words[4:4 + 3 * nv], dtype=np.float64).reshape(nv, 3)
        f, at = [], 4 + 3 * nv
        for _ in range(nf):
            k = int(words[at])
            assert k == 3, f"{path}: face of {k} corners"
            f.append([int(x) for x in words[at + 1:at + 4]])
            at += 1 + k
        return v, np.array(f, dtype=np.int32)
    v, f = [], []
    for line in text:
        p = line.split()
        if not p:
            continue
        if p[0] == "v":
            v.append([float(x) for x in p[1:4]])
        elif p[0] == "f":
            idx = [int(x.split("/")[0]) - 1 for x in p[1:]]
            assert len(idx) == 3, f"{path}: face of {len(idx)} corners"
            f.append(idx)
    return np.array(v, dtype=np.float64), np.array(f, dtype=np.int32)


def to_gifti(mesh: Path, out: Path) -> None:
    import nibabel as nib
    v, f = read_off_or_obj(mesh)
    img = nib.gifti.GiftiImage()
    # Workbench names the surface's structure in its CIFTI output, which
    # nibabel refuses to read without one.
    meta = nib.gifti.GiftiMetaData({"AnatomicalStructurePrimary": "CortexLeft"})
    img.add_gifti_data_array(nib.gifti.GiftiDataArray(
        v.astype(np.float32), intent="NIFTI_INTENT_POINTSET", datatype="NIFTI_TYPE_FLOAT32",
        meta=meta))
    img.add_gifti_data_array(nib.gifti.GiftiDataArray(
        f, intent="NIFTI_INTENT_TRIANGLE", datatype="NIFTI_TYPE_INT32"))
    nib.save(img, str(out))


def with_structure(surface: Path, work: Path) -> Path:
    """The surface, or a copy of it whose pointset names a structure.

    Workbench copies the pointset's AnatomicalStructurePrimary into its
    CIFTI output, which nibabel refuses to read without one.
    """
    import nibabel as nib
    img = nib.load(str(surface))
    points = [a for a in img.darrays if a.intent == nib.nifti1.intent_codes["NIFTI_INTENT_POINTSET"]]
    assert points, f"{surface}: no pointset"
    if "AnatomicalStructurePrimary" in points[0].meta:
        return surface
    points[0].meta["AnatomicalStructurePrimary"] = "CortexLeft"
    copy = work / surface.name
    nib.save(img, str(copy))
    return copy


class Run:
    """What one command took: wall and CPU seconds, peak RSS, its stdout."""

    def __init__(self, cmd):
        with tempfile.NamedTemporaryFile("r", suffix=".time") as t:
            start = time.monotonic()
            r = subprocess.run(["/usr/bin/time", "-f", "%M %U %S", "-o", t.name] + cmd,
                               capture_output=True, text=True)
            self.wall = time.monotonic() - start
            if r.returncode != 0:
                sys.exit(f"{' '.join(cmd)} failed ({r.returncode}):\n{r.stderr[-2000:]}")
            rss_kb, user, system = t.read().strip().split("\n")[-1].split()
        self.rss = int(rss_kb) * 1024
        self.cpu = float(user) + float(system)
        self.stdout = r.stdout


def row_errors(row: np.ndarray, exact: np.ndarray, source: int):
    """Max and mean relative error of a row against an exact field."""
    assert row.shape == exact.shape and row.size > 0
    keep = np.isfinite(exact) & (exact > 0)
    keep[source] = False
    assert keep.sum() > 0 and np.isfinite(row[keep]).all(), "row has unreached vertices"
    rel = np.abs(row[keep].astype(np.float64) - exact[keep]) / exact[keep]
    return float(rel.max()), float(rel.mean())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("mesh", type=Path)
    ap.add_argument("--eps", type=float, default=1e-3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--geodesicd", default=str(HERE.parent / "build" / "bin" / "geodesicd"))
    ap.add_argument("--truth", type=Path, default=HERE.parent.parent / "shared" / "truth")
    ap.add_argument("--keep", type=Path, help="directory to keep the matrices in")
    args = ap.parse_args()

    work = Path(tempfile.mkdtemp(prefix="matrix-bench-", dir=args.keep))
    try:
        surface = args.mesh
        if surface.name.endswith(".gii"):
            surface = with_structure(surface, work)
        else:
            surface = work / (args.mesh.stem + ".surf.gii")
            to_gifti(args.mesh, surface)
        stem = re.sub(r"\.surf$", "", surface.stem)
        def build_and_solve(name, flags):
            """(build s, the matrix's Run, its report, its .npy path)"""
            graph, matrix = work / f"{name}.dgg", work / f"{name}.npy"
            build = Run([args.geodesicd, "build", str(surface), "--eps", str(args.eps),
                         "--out", str(graph), "--quiet", "--json"] + flags)
            solve = Run([
                args.geodesicd, "matrix", "--mesh", str(surface), "--graph", str(graph),
                "--sources", "all", "--targets", "all", "--dtype", "float32",
                "--out", str(matrix), "--threads", str(args.threads), "--json"])
            return build.wall, solve, json.loads(solve.stdout), matrix

        build_s, ours, report, ours_npy = build_and_solve("g", [])
        xbuild_s, xours, _, xours_npy = build_and_solve("xf", ["--exact-fans"])
        ours_s, xours_s = ours.wall, xours.wall
        D = np.load(ours_npy, mmap_mode="r")
        n = D.shape[0]
        assert D.shape == (n, n) and n > 0
        X = np.load(xours_npy, mmap_mode="r")
        assert X.shape == D.shape
        same = all(np.array_equal(D[i:i + 512], X[i:i + 512]) for i in range(0, n, 512))
        # Symmetric where the graph is: sampled blocks against their transposes.
        rng = np.random.default_rng(1)
        rows = np.sort(rng.choice(n, size=min(n, 256), replace=False))
        block = np.asarray(D[rows][:, rows])
        assert np.isfinite(block).all()
        asym = float(np.max(np.abs(block - block.T)))

        wb_path = shutil.which("wb_command")
        wb = W = None
        if wb_path:
            dconn = work / "wb.dconn.nii"
            wb = Run([wb_path, "-surface-geodesic-distance-all-to-all", str(surface), str(dconn)])
            import nibabel as nib
            W = nib.load(str(dconn)).dataobj

        errors = {"ours": [], "wb": []}
        fields = sorted(args.truth.glob(f"{stem}.exact.s*.f64"))
        if not fields:
            for s in np.random.default_rng(7).choice(n, size=min(n, 4), replace=False):
                fields.append(work / f"{stem}.exact.s{s}.f64")
                Run([args.geodesicd, "exact", "--mesh", str(surface), "--source", f"v:{s}",
                     "--out", str(fields[-1])])
        for f in fields:
            s = int(re.search(r"\.s(\d+)\.f64$", f.name).group(1))
            exact = np.fromfile(f, dtype="<f8")
            assert exact.size == n, f"{f}: {exact.size} values for {n} vertices"
            errors["ours"].append(row_errors(np.asarray(D[s]), exact, s))
            if W is not None:
                errors["wb"].append(row_errors(np.asarray(W[s], dtype=np.float64), exact, s))

        def err(name):
            e = errors[name]
            return f"{100 * max(x[0] for x in e):.3g}% / {100 * np.mean([x[1] for x in e]):.3g}%"

        print(f"All pairs of {surface.name} ({n} vertices), eps {args.eps:g}, "
              f"geodesicd on {args.threads} threads; graph built in {build_s:.1f} s")
        print()
        print("| tool | wall s | CPU s | peak RSS MiB | max / mean error vs exact |")
        print("|---|---:|---:|---:|---:|")
        print(f"| geodesicd matrix, float32 .npy | {ours.wall:.1f} | {ours.cpu:.1f} | "
              f"{ours.rss / 2**20:.0f} | {err('ours')} |")
        print(f"| the same on a graph built --exact-fans | {xours.wall:.1f} | {xours.cpu:.1f} | "
              f"{xours.rss / 2**20:.0f} | {err('ours') if same else 'differs'} |")
        if wb is not None:
            print(f"| wb_command -surface-geodesic-distance-all-to-all | {wb.wall:.1f} | "
                  f"{wb.cpu:.1f} | {wb.rss / 2**20:.0f} | {err('wb')} |")
            print()
            print(f"wb_command / geodesicd wall time: {wb.wall / ours_s:.1f}x "
                  f"(with the graph build: {wb.wall / (ours_s + build_s):.1f}x); "
                  f"on the --exact-fans graph: {wb.wall / xours_s:.1f}x "
                  f"(with its build, {xbuild_s:.1f} s: {wb.wall / (xours_s + xbuild_s):.1f}x)")
        print(f"largest |D - D^T| over {len(rows)}^2 sampled entries: {asym:.3g}; "
              f"matrix reported {report['seconds']:.1f} s, {report['bytes']} bytes; "
              f"the --exact-fans matrix is {'the same' if same else 'NOT the same'}")
        assert same, "exact fans changed the matrix"
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
