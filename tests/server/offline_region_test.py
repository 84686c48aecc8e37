#!/usr/bin/env python3
"""geodesicd build/field/matrix on a region of the bundled mesh (the cow
without the right half of a band through its body): the region's matrix in
its own ids and in the parent's (+inf outside the region), masks as text
and .npy, vertex and face masks alike, the region's graph refused with the
whole mesh, and mistakes named.
Usage: offline_region_test.py BUILD_BIN_DIR SOURCE_DIR"""
import json
import os
import sys
import tempfile

import numpy as np
import scipy.sparse

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from checklist import Checklist  # noqa: E402
from geodesicd_runner import geodesicd_runner, read_obj  # noqa: E402

bin_dir, src = sys.argv[1], sys.argv[2]
mesh = os.path.join(src, "data", "spot.obj")
check = Checklist()
run = geodesicd_runner(bin_dir)


def same(name, a, b):
    """Equal bit for bit, after both are non-empty, finite and of one shape."""
    a, b = np.asarray(a), np.asarray(b)
    ok = a.size > 0 and a.shape == b.shape and np.isfinite(a).all() and np.isfinite(b).all()
    detail = f"shapes {a.shape} {b.shape}"
    if ok:
        ok = np.array_equal(a, b)
        detail = f"{np.sum(a != b)} entries differ"
    return check(name, ok, detail)


def refused(name, args, needle):
    r = run(*args, expect_ok=False)
    check(name, r.returncode != 0 and needle in r.stderr, f"exit {r.returncode}: {r.stderr}")


positions, faces = read_obj(mesh)
n = len(positions)
check("the mesh has faces and vertices", n > 0 and len(faces) > 0, (n, len(faces)))
in_mask = ~((np.abs(positions[:, 1] - 0.1) < 0.08) & (positions[:, 0] > 0))
kept_faces = np.flatnonzero(in_mask[faces].all(axis=1))
inside = np.unique(faces[kept_faces])  # the region's vertices, in parent order
outside = np.setdiff1d(np.arange(n), inside)
check("the band removes vertices and leaves most",
      0 < len(outside) < n // 4 and len(inside) > 0, (len(inside), len(outside)))

with tempfile.TemporaryDirectory() as work:
    def path(name):
        return os.path.join(work, name)

    with open(path("mask.txt"), "w") as f:
        f.write("# the cow without half a band\n")
        f.write("".join(f"{v}\n" for v in np.flatnonzero(in_mask)))
    np.save(path("mask_bool.npy"), in_mask)
    np.save(path("mask_ids.npy"), np.flatnonzero(in_mask).astype(np.int64))
    with open(path("faces.txt"), "w") as f:
        f.write("".join(f"{i}\n" for i in kept_faces))
    region = ["--region-vertices", path("mask.txt")]

    # 1. The region's graph: its own mesh, which the whole mesh cannot use.
    built = json.loads(run("build", mesh, *region, "--eps", "1e-2", "--out", path("r.dgg"),
                           "--json").stdout)
    check("build --json reports the region and its parent",
          built["region_vertices"] == len(inside) == built["vertices"] and
          built["parent_vertices"] == n and built["region_faces"] == len(kept_faces), built)
    refused("the region's graph is refused with the whole mesh",
            ["field", "--mesh", mesh, "--graph", path("r.dgg"), "--source", "v:0"],
            "built for another mesh")
    run("build", mesh, "--eps", "1e-2", "--out", path("whole.dgg"))
    refused("the whole mesh's graph is refused with the region",
            ["field", "--mesh", mesh, *region, "--graph", path("whole.dgg"), "--source", "v:0"],
            "built for another mesh")
    common = ["--mesh", mesh, "--graph", path("r.dgg")]

    def matrix(out, *args):
        r = run("matrix", *common, *args, "--dtype", "float64", "--out", path(out), "--json")
        return json.loads(r.stdout), np.load(path(out)) if out.endswith(".npy") else None

    # 2. In the region's ids, then the parent's: the same numbers, placed at
    # the parent's ids, +inf in every row and column outside the region.
    report, own = matrix("own.npy", *region, "--sources", "all", "--targets", "all")
    check("region ids: m x m", own.shape == (len(inside), len(inside)), own.shape)
    check("region ids: finite (the region is connected)", own.size > 0 and np.isfinite(own).all())
    check("matrix --json reports the region",
          report["region_vertices"] == len(inside) and report["parent_vertices"] == n, report)
    report, parent = matrix("parent.npy", *region, "--parent-ids", "--sources", "all",
                            "--targets", "all")
    check("parent ids: n x n", parent.shape == (n, n), parent.shape)
    check("parent ids: --json rows and columns are the parent's",
          report["rows"] == n and report["columns"] == n, report)
    check("parent ids: rows outside the region are +inf",
          len(outside) > 0 and np.all(np.isposinf(parent[outside, :])))
    check("parent ids: columns outside the region are +inf",
          len(outside) > 0 and np.all(np.isposinf(parent[:, outside])))
    same("parent ids: inside, the region's matrix", parent[np.ix_(inside, inside)], own)

    # 3. The region forces detours: never shorter than on the whole mesh
    # (within the graphs' eps), and longer for some pairs.
    rows = [int(inside[0]), int(inside[len(inside) // 2])]
    specs = [f"v:{v}" for v in rows]
    run("matrix", "--mesh", mesh, "--graph", path("whole.dgg"), "--sources", *specs,
        "--targets", "all", "--dtype", "float64", "--out", path("whole.npy"))
    whole = np.load(path("whole.npy"))[:, inside]
    ours = parent[np.ix_(rows, inside)]
    check("whole-mesh rows are finite", whole.size > 0 and np.isfinite(whole).all())
    check("region distances are never shorter", np.all(ours * 1.01 >= whole),
          np.min(ours * 1.01 - whole))
    check("some region distances are longer (a detour)", np.any(ours > 1.2 * whole))

    # 4. Masks as .npy (bools, ids) and as faces give the same region.
    for mask in ("mask_bool.npy", "mask_ids.npy"):
        _, m = matrix(f"m_{mask}", "--region-vertices", path(mask), "--sources", "all",
                      "--targets", "all")
        same(f"a {mask} mask is the text mask", m, own)
    _, m = matrix("m_faces.npy", "--region-faces", path("faces.txt"), "--sources", "all",
                  "--targets", "all")
    same("the kept faces as a face mask are the vertex mask", m, own)

    # 5. Parent-id points, a sparse matrix and a field in parent ids.
    v = int(inside[len(inside) // 3])
    _, row = matrix("row.npy", *region, "--parent-ids", "--sources", f"v:{v}", "--targets", "all")
    same("a parent-id source is its row in parent ids",
         row[:, inside], parent[np.ix_([v], inside)])
    check("a parent-id row is +inf outside", np.all(np.isposinf(row[:, outside])))
    run("field", *common, *region, "--parent-ids", "--source", f"v:{v}", "--out", path("f.npy"))
    field = np.load(path("f.npy"))
    check("a parent-id field has one value per parent vertex", field.shape == (n,), field.shape)
    same("a parent-id field is the row, inside", field[inside], parent[v, inside])
    check("a parent-id field is +inf outside", np.all(np.isposinf(field[outside])))
    run("matrix", *common, *region, "--parent-ids", "--sources", "all", "--targets",
        f"v:{v}", f"v:{inside[-1]}", "--dtype", "float64", "--radius", "0.5",
        "--out", path("sparse.npz"))
    sparse = scipy.sparse.load_npz(path("sparse.npz"))
    dense = parent[:, [v, int(inside[-1])]]
    check("sparse in parent ids: n rows", sparse.shape == (n, 2), sparse.shape)
    got = sparse.toarray()
    within = dense <= 0.5
    check("sparse in parent ids: the dense entries within the radius",
          within.any() and np.array_equal(sparse.toarray()[within], dense[within]) and
          np.count_nonzero(got[~within]) == 0 and sparse.nnz == within.sum())
    # A row over every parent vertex: the region's columns, put in the
    # parent's order.
    run("matrix", *common, *region, "--parent-ids", "--sources", f"v:{v}", "--targets", "all",
        "--dtype", "float64", "--radius", "0.5", "--out", path("sparse_row.npz"))
    sparse_row = scipy.sparse.load_npz(path("sparse_row.npz")).toarray()
    near = row <= 0.5
    check("a sparse parent-id row over all targets: the dense row's entries within the radius",
          sparse_row.shape == row.shape and near.any() and not near.all() and
          np.array_equal(sparse_row[near], row[near]) and
          np.count_nonzero(sparse_row[~near]) == 0)

    # 6. Mistakes, named.
    o = int(outside[0])
    refused("a source outside the region is named",
            ["matrix", *common, *region, "--parent-ids", "--sources", f"v:{o}", "--targets",
             "all", "--dtype", "float64", "--out", path("bad.npy")],
            f"v:{o} is outside the region")
    refused("a field source outside the region is named",
            ["field", *common, *region, "--parent-ids", "--source", f"v:{o}"],
            f"v:{o} is outside the region")
    with open(path("big.txt"), "w") as f:
        f.write(f"0\n{n + 5}\n")
    refused("a mask id out of range is named with the mesh's size",
            ["build", mesh, "--region-vertices", path("big.txt"), "--out", path("bad.dgg")],
            f"vertex id {n + 5} is out of range: the mesh has {n} vertices")
    with open(path("words.txt"), "w") as f:
        f.write("0\nseven\n")
    refused("a mask line that is no id is named", ["build", mesh, "--region-vertices",
                                                  path("words.txt"), "--out", path("bad.dgg")],
            "words.txt line 2")
    with open(path("lonely.txt"), "w") as f:
        f.write("0\n")
    refused("an empty region is refused",
            ["build", mesh, "--region-vertices", path("lonely.txt"), "--out", path("bad.dgg")],
            "empty")
    refused("--parent-ids without a region is refused",
            ["field", "--mesh", mesh, "--graph", path("whole.dgg"), "--parent-ids",
             "--source", "v:0"], "needs a region")
    check("no output was left by the refusals",
          not os.path.exists(path("bad.npy")) and not os.path.exists(path("bad.dgg")))

check.finish()
