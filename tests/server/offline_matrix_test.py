#!/usr/bin/env python3
"""geodesicd matrix on the bundled mesh: dense rows against single-source
fields, the all-pairs matrix's symmetry, the sparse .npz against the dense
matrix, point lists against `distance --pairs`, errors that leave nothing
behind, and memory that does not grow with the matrix.
Usage: offline_matrix_test.py BUILD_BIN_DIR SOURCE_DIR"""
import json
import os
import sys
import tempfile

import numpy as np
import scipy.sparse

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from checklist import Checklist  # noqa: E402
from geodesicd_runner import geodesicd_runner  # noqa: E402

bin_dir, src = sys.argv[1], sys.argv[2]
mesh = os.path.join(src, "data", "spot.obj")
check = Checklist()
run = geodesicd_runner(bin_dir)


def same(name, a, b):
    """Equal bit for bit (NaN never expected), after both are non-empty,
    finite and of one shape."""
    a, b = np.asarray(a), np.asarray(b)
    ok = a.size > 0 and a.shape == b.shape and np.isfinite(a).all() and np.isfinite(b).all()
    detail = f"shapes {a.shape} {b.shape}"
    if ok:
        ok = np.array_equal(a, b)
        detail = f"{np.sum(a != b)} entries differ, largest by {np.max(np.abs(a - b))}"
    return check(name, ok, detail)


with tempfile.TemporaryDirectory() as work:
    graph = os.path.join(work, "g.dgg")
    run("build", mesh, "--eps", "1e-2", "--out", graph)
    common = ["--mesh", mesh, "--graph", graph]
    n = int(json.loads(run("info", mesh, "--json").stdout)["vertices"])

    def matrix(out, *args):
        r = run("matrix", *common, *args, "--out", os.path.join(work, out), "--json")
        return json.loads(r.stdout)

    # 1. Vertex rows are the single-source fields, bit for bit; float32 is
    # the float64 matrix rounded.
    rows = [0, 1, 777, 1500, n - 1]
    specs = [f"v:{v}" for v in rows]
    report = matrix("rows64.npy", "--sources", *specs, "--targets", "all", "--dtype", "float64")
    d64 = np.load(os.path.join(work, "rows64.npy"))
    check("float64 rows: dtype and shape",
          d64.dtype == np.float64 and d64.shape == (len(rows), n), (d64.dtype, d64.shape))
    check("--json reports the shape and the file's size",
          report["rows"] == len(rows) and report["columns"] == n and
          report["dtype"] == "float64" and
          report["bytes"] == os.path.getsize(os.path.join(work, "rows64.npy")), report)
    for k, v in enumerate(rows):
        field = os.path.join(work, f"field{v}.npy")
        run("field", *common, "--source", f"v:{v}", "--out", field)
        same(f"row of v:{v} is its field", d64[k], np.load(field))
    matrix("rows32.npy", "--sources", *specs, "--targets", "all", "--dtype", "float32")
    d32 = np.load(os.path.join(work, "rows32.npy"))
    check("float32 rows: dtype", d32.dtype == np.float32, d32.dtype)
    same("float32 is the float64 matrix rounded", d32, d64.astype(np.float32))

    # 2. All pairs. Each undirected DGG edge is stored once from each end
    # with one float32 weight (core/dgg/candidate_edges.cc gives both copies
    # the shorter), so graph distances are symmetric. A path's float64 sum
    # taken from the other end could in principle round differently after
    # three or more hops; this graph (the same bytes on every build) shows
    # none, so any difference is a regression in how rows are solved.
    report = matrix("all.npy", "--sources", "all", "--targets", "all", "--dtype", "float64")
    full = np.load(os.path.join(work, "all.npy"))
    check("all pairs: n x n", full.shape == (n, n), full.shape)
    check("all pairs: finite (spot is one component)", np.isfinite(full).all())
    check("all pairs: zero diagonal", np.all(np.diag(full) == 0))
    check("all pairs: positive off the diagonal", np.all(full + np.eye(n) > 0))
    same("all pairs: symmetric", full, full.T)
    same("all pairs: its rows are the rows asked for alone", full[rows], d64)

    # Memory stays bounded by the graph, the mesh and a few rows per thread:
    # the baseline is the same process computing one row, and the float32
    # all-pairs run (34 MB of matrix) must stay within half the matrix of
    # it. Holding the matrix, float32 or float64, would pass that bound.
    one = matrix("one.npy", "--sources", "v:0", "--targets", "all", "--dtype", "float32",
                 "--threads", "2")
    big = matrix("big.npy", "--sources", "all", "--targets", "all", "--dtype", "float32",
                 "--threads", "2")
    matrix_bytes = n * n * 4
    check("all pairs float32: the file is the matrix plus its header",
          big["bytes"] == matrix_bytes + 128, big)
    check("all pairs float32: peak memory well below the matrix's",
          0 < one["peak_rss_bytes"] and
          big["peak_rss_bytes"] < one["peak_rss_bytes"] + matrix_bytes // 2,
          (one["peak_rss_bytes"], big["peak_rss_bytes"], matrix_bytes))
    same("float32 all pairs is the float64 matrix rounded", np.load(os.path.join(work, "big.npy")),
         full.astype(np.float32))
    matrix("one-thread.npy", "--sources", "all", "--targets", "all", "--dtype", "float32",
           "--threads", "1")
    with open(os.path.join(work, "big.npy"), "rb") as a, \
            open(os.path.join(work, "one-thread.npy"), "rb") as b:
        check("the file is the same bytes on one thread", a.read() == b.read())

    # 3. The sparse matrix within a radius is the dense one thresholded.
    radius = float(np.quantile(full, 0.1))
    for dtype, np_dtype in (("float64", np.float64), ("float32", np.float32)):
        out = f"within-{dtype}.npz"
        report = matrix(out, "--sources", "all", "--targets", "all", "--dtype", dtype,
                        "--radius", str(radius))
        sparse = scipy.sparse.load_npz(os.path.join(work, out)).tocsr()
        keep = full <= radius
        check(f"npz {dtype}: shape, dtype, nonzeros",
              sparse.shape == (n, n) and sparse.dtype == np_dtype and
              sparse.nnz == report["nonzeros"] == keep.sum() > n,
              (sparse.shape, sparse.dtype, sparse.nnz, report, keep.sum()))
        check(f"npz {dtype}: --json bytes is the file's size",
              report["bytes"] == os.path.getsize(os.path.join(work, out)), report)
        pattern = np.zeros((n, n), dtype=bool)
        pattern[np.repeat(np.arange(n), np.diff(sparse.indptr)), sparse.indices] = True
        check(f"npz {dtype}: the pattern is the entries within the radius, diagonal included",
              np.array_equal(pattern, keep), f"{np.sum(pattern != keep)} differ")
        same(f"npz {dtype}: the values are the dense ones", sparse.data,
             full[keep].astype(np_dtype))

    # 4. Point lists: face, edge and snapped points from a file, against
    # `distance --pairs` pair by pair.
    points = os.path.join(work, "sources.txt")
    with open(points, "w") as f:
        f.write("# face, edge and position sources\nf:12:0.2,0.3,0.5\n\n"
                "f:100:0.1,0.1,0.8\ne:5:0.25\nxyz:0.1,0.2,0.3\nv:7\n")
    sources = ["f:12:0.2,0.3,0.5", "f:100:0.1,0.1,0.8", "e:5:0.25", "xyz:0.1,0.2,0.3", "v:7"]
    targets = ["v:0", "v:1500", "v:7", f"v:{n - 1}"]
    matrix("sub.npy", "--sources", f"@{points}", "--targets", *targets, "--dtype", "float64")
    sub = np.load(os.path.join(work, "sub.npy"))
    pairs = os.path.join(work, "pairs.txt")
    with open(pairs, "w") as f:
        f.writelines(f"{s} {t}\n" for s in sources for t in targets)
    answers = json.loads(run("distance", *common, "--pairs", pairs, "--json").stdout)
    same("point lists: entries are distance --pairs' answers", sub,
         np.array([a["distance"] for a in answers]).reshape(len(sources), len(targets)))

    # 5. Errors name the problem, exit non-zero and leave no file behind.
    def refused(name, out, args, expect):
        before = set(os.listdir(work))
        r = run("matrix", *common, *args, "--out", os.path.join(work, out), expect_ok=False)
        left = set(os.listdir(work)) - before
        check(name, r.returncode != 0 and expect in r.stderr and not left,
              (r.returncode, r.stderr, left))

    dense = ["--sources", "v:0", "--targets", "all", "--dtype", "float64"]
    refused("an unknown vertex is named", "bad.npy",
            ["--sources", "v:0", f"v:{n}", "--targets", "all", "--dtype", "float64"], f"v:{n}")
    bad_list = os.path.join(work, "bad.txt")
    with open(bad_list, "w") as f:
        f.write("v:0\n# fine so far\nv:99999\n")
    refused("a bad point in a file is named with its file and line", "bad.npy",
            ["--sources", f"@{bad_list}", "--targets", "all", "--dtype", "float64"],
            f"{bad_list} line 3: v:99999")
    refused("a missing points file is named", "bad.npy",
            ["--sources", "@" + os.path.join(work, "none.txt"), "--targets", "all",
             "--dtype", "float64"], "none.txt")
    refused("a bad dtype is named", "bad.npy",
            ["--sources", "v:0", "--targets", "all", "--dtype", "float16"], "float16")
    refused("--radius with .npy is refused", "bad.npy", dense + ["--radius", "0.5"],
            "'.npy'")
    refused("a dense matrix as .npz is refused", "bad.npz", dense, "'.npz'")
    for r in ("0", "-1", "inf", "nan"):
        refused(f"--radius {r} is refused", "bad.npz", dense + ["--radius", r],
                f"got '{r}'")
    refused("a missing directory is refused", os.path.join("no-such-dir", "d.npy"), dense,
            "no-such-dir")
    refused("a file as the directory is refused", os.path.join("sources.txt", "d.npz"),
            dense + ["--radius", "0.5"], "sources.txt")
    # The output was not replaced by a failed run either.
    run("matrix", *common, *dense, "--out", os.path.join(work, "kept.npy"))
    kept = np.load(os.path.join(work, "kept.npy"))
    refused("a failing run leaves the old output", "kept.npy",
            ["--sources", "v:0", f"v:{n}", "--targets", "all", "--dtype", "float64"], f"v:{n}")
    same("a failing run leaves the old output intact", np.load(os.path.join(work, "kept.npy")),
         kept)

check.finish()
