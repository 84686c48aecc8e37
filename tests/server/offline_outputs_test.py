#!/usr/bin/env python3
"""The offline commands' result files: every format by extension, labels,
path polylines and snap distances, checked against each other and against
the raw fields. Usage: offline_outputs_test.py BUILD_BIN_DIR SOURCE_DIR"""
import json
import os
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from checklist import Checklist  # noqa: E402
from geodesicd_runner import geodesicd_runner  # noqa: E402

bin_dir, src = sys.argv[1], sys.argv[2]
mesh = os.path.join(src, "data", "spot.obj")
check = Checklist()
run = geodesicd_runner(bin_dir)


with tempfile.TemporaryDirectory() as work:
    graph = os.path.join(work, "g.dgg")
    built = json.loads(run("build", mesh, "--eps", "1e-2", "--out", graph, "--json").stdout)
    common = ["--mesh", mesh, "--graph", graph]

    # info tells what the mesh will hold in memory before anything is built.
    info = json.loads(run("info", mesh, "--json").stdout)
    check("info and build report the same mesh bytes",
          info["mesh_bytes"] == built["mesh_bytes"] > info["vertices"] * 3 * 8, (info, built))

    # One field in every format: the same numbers.
    for ext in ("f64", "npy", "csv", "ply"):
        run("field", *common, "--source", "v:0", "--source", "v:1500", "--out",
            os.path.join(work, "f." + ext))
    raw = np.fromfile(os.path.join(work, "f.f64"), dtype="<f8")
    check("npy equals f64", np.array_equal(np.load(os.path.join(work, "f.npy")), raw))
    csv = np.loadtxt(os.path.join(work, "f.csv"), delimiter=",", skiprows=1)
    check("csv equals f64 (full precision)",
          np.array_equal(csv[:, 0], np.arange(len(raw))) and np.array_equal(csv[:, 1], raw))
    with open(os.path.join(work, "f.ply")) as f:
        lines = f.read().splitlines()
    body = lines[lines.index("end_header") + 1:][:len(raw)]
    check("ply carries the distance of every vertex",
          np.array_equal(np.array([float(l.split()[-1]) for l in body]), raw))

    # Labels are the index of the nearest source: the smaller of the two
    # single-source fields (exact ties are possible, but not at these sources).
    run("field", *common, "--source", "v:0", "--source", "v:1500", "--labels-out",
        os.path.join(work, "l.npy"))
    for k, s in enumerate(("v:0", "v:1500")):
        run("field", *common, "--source", s, "--out", os.path.join(work, f"s{k}.f64"))
    s0 = np.fromfile(os.path.join(work, "s0.f64"), dtype="<f8")
    s1 = np.fromfile(os.path.join(work, "s1.f64"), dtype="<f8")
    labels = np.load(os.path.join(work, "l.npy"))
    check("labels are uint32", labels.dtype == np.uint32)
    check("labels name the nearer source", np.array_equal(labels, (s1 < s0).astype(np.uint32)),
          f"{np.sum(labels != (s1 < s0))} vertices differ")
    check("the two-source field is the smaller one", np.array_equal(raw, np.minimum(s0, s1)))

    # Unknown formats are refused by name, before any work, and write nothing.
    r = run("field", *common, "--source", "v:0", "--out", os.path.join(work, "f.txt"),
            expect_ok=False)
    check("field refuses .txt", r.returncode != 0 and "'.txt'" in r.stderr and
          not os.path.exists(os.path.join(work, "f.txt")), r.stderr)
    r = run("field", *common, "--source", "v:0", "--labels-out", os.path.join(work, "l.f64"),
            expect_ok=False)
    check("labels refuse .f64", r.returncode != 0 and ".npy, .csv, .u32" in r.stderr, r.stderr)

    # A pairs file line without exactly two points is refused by file and
    # line, never dropped or truncated silently.
    bad_pairs = os.path.join(work, "bad.pairs")
    with open(bad_pairs, "w") as f:
        f.write("v:0 v:10\n\nv:1 v:2 v:3\n")
    r = run("distance", *common, "--pairs", bad_pairs, expect_ok=False)
    check("a pairs line with three points is refused by line",
          r.returncode != 0 and "bad.pairs line 3: expected two points, found 3" in r.stderr,
          r.stderr)
    # Exact pairs with exact landmarks: the same distances, fewer windows,
    # and the landmarks' one-time cost on stderr.
    spread = os.path.join(work, "spread.pairs")
    with open(spread, "w") as f:
        f.write("".join(f"v:{a} v:{b}\n" for a, b in
                        ((0, 1500), (10, 2900), (700, 2200), (2000, 40), (1234, 2345))))
    plain = json.loads(run("distance", *common, "--pairs", spread, "--exact", "--json").stdout)
    r = run("distance", *common, "--pairs", spread, "--exact", "--exact-landmarks", "8", "--json")
    marked = json.loads(r.stdout)
    check("pairs are answered exact with and without landmarks",
          len(plain) == len(marked) == 5 and all(x["exact"] for x in plain + marked) and
          all(0 < x["distance"] < float("inf") for x in plain + marked), (plain, marked))
    check("exact landmarks give the same exact distances",
          all(abs(a["distance"] - b["distance"]) <= 1e-12 * a["distance"]
              for a, b in zip(plain, marked)), (plain, marked))
    check("exact landmarks leave fewer windows",
          sum(x["windows"] for x in marked) < sum(x["windows"] for x in plain),
          ([x["windows"] for x in plain], [x["windows"] for x in marked]))
    check("the landmarks' cost is reported", "exact landmarks: 8 fields in" in r.stderr, r.stderr)
    # Kept beside the graph with --save-exact-landmarks, read back by later
    # runs asking for as many; another count is computed, not read.
    kept = graph + ".exact-landmarks"
    check("no landmarks are kept unasked", not os.path.exists(kept), os.listdir(work))
    r = run("distance", *common, "--pairs", spread, "--exact", "--exact-landmarks", "8",
            "--save-exact-landmarks", "--json")
    check("--save-exact-landmarks keeps them beside the graph",
          os.path.exists(kept) and f"kept in {kept}" in r.stderr, r.stderr)
    r = run("distance", *common, "--pairs", spread, "--exact", "--exact-landmarks", "8", "--json")
    again = json.loads(r.stdout)
    check("a later run reads them back", f"8 fields read from {kept}" in r.stderr, r.stderr)
    check("read back, they give the same answers from as many windows",
          [(x["distance"], x["windows"]) for x in again] ==
          [(x["distance"], x["windows"]) for x in marked], (again, marked))
    r = run("distance", *common, "--pairs", spread, "--exact", "--exact-landmarks", "4", "--json")
    check("another count is computed, saying why the file was not read",
          "holds 8 landmarks, not the 4 asked for" in r.stderr and
          "exact landmarks: 4 fields in" in r.stderr, r.stderr)
    for value in ("-1", "0", "nan"):
        r = run("field", *common, "--source", "v:0", "--max-distance", value, "--out",
                os.path.join(work, "m.f64"), expect_ok=False)
        check(f"field refuses --max-distance {value}",
              r.returncode != 0 and "--max-distance" in r.stderr, r.stderr)

    # A path as a polyline: its segments add up to the distance reported.
    out = run("distance", *common, "--from", "f:0:0.2,0.3,0.5", "--to", "xyz:0.3,0.1,0",
              "--path-out", os.path.join(work, "p.obj"), "--json").stdout
    d = json.loads(out)
    with open(os.path.join(work, "p.obj")) as f:
        rows = f.read().splitlines()
    pts = np.array([[float(x) for x in l.split()[1:]] for l in rows if l.startswith("v ")])
    length = np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=1))
    check("obj polyline has one l line over every vertex",
          rows[-1] == "l " + " ".join(str(i + 1) for i in range(len(pts))))
    check("polyline length is the path's length",
          abs(length - d["path_length"]) <= 1e-9 * d["path_length"],
          f"{length} vs {d['path_length']}")
    check("the path is no longer than the graph distance",
          0 < d["path_length"] <= d["distance"] * (1 + 1e-6), f"{length} vs {d['distance']}")
    plain = json.loads(run("distance", *common, "--from", "f:0:0.2,0.3,0.5", "--to",
                           "xyz:0.3,0.1,0", "--json").stdout)
    check("one distance per pair, with or without its path", plain["distance"] == d["distance"],
          f"{plain['distance']} vs {d['distance']}")
    check("snap distance reported for xyz: only",
          d["from_snap_distance"] is None and d["to_snap_distance"] > 0)
    for ext in ("csv", "ply"):
        run("distance", *common, "--from", "v:0", "--to", "v:1500", "--path-out",
            os.path.join(work, "p." + ext))
    with open(os.path.join(work, "p.csv")) as f:
        check("csv polyline has a header", f.readline().strip() == "x,y,z")

    # A bow tie: two triangles that share only vertex 0, which is therefore
    # non-manifold. info reports it and exits non-zero; build refuses it
    # naming the vertex and the flag; with the flag the vertex is split.
    bowtie = os.path.join(work, "bowtie.obj")
    with open(bowtie, "w") as f:
        f.write("v 0 0 0\nv 1 0 0\nv 0 1 0\nv -1 0 0\nv 0 -1 0\nf 1 2 3\nf 1 4 5\n")
    r = run("info", bowtie, expect_ok=False)
    check("info exits non-zero for an unusable mesh", r.returncode == 3 and "non-manifold" in r.stdout,
          r.stdout + r.stderr)
    r = run("build", bowtie, "--eps", "0.1", "--out", os.path.join(work, "b.dgg"), expect_ok=False)
    check("build refuses it, naming the vertex and the flag",
          r.returncode != 0 and "vertex 0" in r.stderr and "--repair-non-manifold" in r.stderr, r.stderr)
    b = json.loads(run("build", bowtie, "--eps", "0.1", "--out", os.path.join(work, "b.dgg"),
                       "--repair-non-manifold", "--json").stdout)
    check("with --repair-non-manifold the vertex is split", b["vertices"] == 6, b)
    d = json.loads(run("distance", "--mesh", bowtie, "--repair-non-manifold", "--graph",
                       os.path.join(work, "b.dgg"), "--from", "v:1", "--to", "v:2", "--json").stdout)
    check("and the repaired mesh answers", abs(d["distance"] - 2 ** 0.5) < 1e-6, d)

    # check: the graph against the exact engine at every vertex. Its own
    # figures must agree with the fields the other commands write.
    c = json.loads(run("check", *common, "--sources", "3", "--seed", "5", "--json").stdout)
    check("check is sound and within the contract on the sample",
          c["sound"] and c["within_limit"] and 0 < c["max_error_eps"] <= 1.5
          and 0 < c["mean_error_eps"] <= 0.3 and len(c["sources"]) == 3, c)
    check("check compares every vertex but the source",
          all(r["compared"] == info["vertices"] - 1 for r in c["sources"]), c["sources"])
    again = json.loads(run("check", *common, "--sources", "3", "--seed", "5", "--json").stdout)
    check("the same seed, the same sources and figures",
          [r["source"] for r in again["sources"]] == [r["source"] for r in c["sources"]]
          and again["max_error_eps"] == c["max_error_eps"])
    worst = max(c["sources"], key=lambda r: r["max_error_eps"])
    run("exact", "--mesh", mesh, "--source", worst["source"], "--out",
        os.path.join(work, "e.f64"))
    run("field", *common, "--source", worst["source"], "--out", os.path.join(work, "g.f64"))
    ex = np.fromfile(os.path.join(work, "e.f64"), dtype="<f8")
    gr = np.fromfile(os.path.join(work, "g.f64"), dtype="<f8")
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(ex > 0, (gr - ex) / ex, 0.0)
    check("check's worst error is the one exact and field give",
          abs(rel.max() / built["epsilon"] - worst["max_error_eps"]) < 1e-9
          and int(rel.argmax()) == worst["worst_vertex"], (rel.max(), worst))
    only = json.loads(run("check", *common, "--source", "f:0:0.2,0.3,0.5", "--json").stdout)
    check("--source alone checks only that point",
          [r["source"][:4] for r in only["sources"]] == ["f:0:"] and only["sound"], only)
    r = run("check", *common, "--sources", "3", "--fail-above", "0.05", expect_ok=False)
    check("--fail-above fails past the limit, naming the worst vertex",
          r.returncode == 1 and "exceeds --fail-above 0.05" in r.stderr and "vertex" in r.stderr,
          r.stderr)
    r = run("check", "--mesh", bowtie, "--repair-non-manifold", "--graph", graph, expect_ok=False)
    check("check refuses a graph of another mesh",
          r.returncode == 1 and "another mesh" in r.stderr, r.stderr)

    e = json.loads(run("exact", "--mesh", mesh, "--source", "xyz:0,0,0", "--json").stdout)
    check("exact reports the snap distance", e["snap_distance"] > 0)

    # build --max-error: a certified graph, its certificate in --json and
    # beside the graph, shown by info and repeated by check.
    cert_graph = os.path.join(work, "c.dgg")
    cb = json.loads(run("build", mesh, "--max-error", "1e-2", "--sources", "8", "--seed", "3",
                        "--out", cert_graph, "--json").stdout)
    cert = cb.get("certificate", {})
    check("certified build keeps every plain build key", set(built) <= set(cb),
          set(built) - set(cb))
    check("certificate has its keys, in order",
          list(cert) == ["max_error_bound", "epsilon", "measured_max_error",
                         "measured_mean_error", "sources", "seed", "sound", "builds"], cert)
    check("certificate holds what it says",
          cert["max_error_bound"] == 1e-2 and cert["epsilon"] == cb["epsilon"] < 1e-2
          and 0 < cert["measured_mean_error"] < cert["measured_max_error"] < 1e-2
          and cert["sources"] == 8 and cert["seed"] == 3 + cert["builds"] - 1
          and cert["sound"] is True and cert["builds"] >= 1, cert)
    check("the sidecar is written beside the graph",
          os.path.exists(cert_graph + ".certificate.json"))
    ci = json.loads(run("info", cert_graph, "--json").stdout)
    check("info --json shows the certificate", ci.get("certificate") == cert, ci)
    check("info shows it as text", "certified max error 0.01" in run("info", cert_graph).stdout)
    rc = json.loads(run("check", "--mesh", mesh, "--graph", cert_graph, "--sources", "8",
                        "--seed", str(cert["seed"]), "--json").stdout)
    check("check with the certificate's sources and seed repeats its max",
          abs(rc["max_error_eps"] * rc["epsilon"] - cert["measured_max_error"])
          <= 1e-12 * cert["measured_max_error"], (rc["max_error_eps"], cert))
    # A sidecar is believed only beside the graph it measured.
    with open(cert_graph + ".certificate.json") as f:
        sidecar = f.read()
    with open(graph + ".certificate.json", "w") as f:
        f.write(sidecar)
    r = run("info", graph, "--json")
    check("a certificate of another graph is ignored, and said so",
          "certificate" not in json.loads(r.stdout) and "certifies another graph" in r.stderr,
          r.stdout + r.stderr)
    run("build", mesh, "--eps", "1e-2", "--out", cert_graph)
    check("a plain build over a certified graph removes its certificate",
          not os.path.exists(cert_graph + ".certificate.json")
          and "certificate" not in json.loads(run("info", cert_graph, "--json").stdout))
    for args, says in ((["--eps", "1e-2", "--max-error", "1e-2"], "excludes"),
                       (["--sources", "4"], "requires --max-error"),
                       (["--max-error", "1e-2", "--part", "0/2"], "--part"),
                       (["--max-error", "1.5"], "(0, 1)")):
        r = run("build", mesh, *args, "--out", os.path.join(work, "x.dgg"), expect_ok=False)
        check(f"build {' '.join(args)} is refused", r.returncode != 0 and says in r.stderr,
              r.stderr)

    # A field in a new process lays its per-node arrays (labels, fans and
    # the answer) in memory that loading the mesh freed,
    # rather than faulting in fresh pages: on a mesh whose arrays are each
    # past glibc's default mmap threshold (128 KiB, so each was a mapping of
    # its own before), fewer faults than a third of one array's pages. Needs
    # the shared meshes (GEODESIC_SHARED_DIR): fails without them.
    shared = os.environ.get("GEODESIC_SHARED_DIR", os.path.join(src, "..", "shared"))
    fertility = os.path.join(shared, "meshes", "fertility.off")
    check("the shared meshes are there", os.path.exists(fertility), fertility)
    if os.path.exists(fertility):
        big_graph = os.path.join(work, "fertility.dgg")
        run("build", fertility, "--eps", "1e-2", "--out", big_graph)
        f = json.loads(run("field", "--mesh", fertility, "--graph", big_graph, "--source",
                           "v:17", "--out", os.path.join(work, "big.f64"), "--json").stdout)
        array_pages = f["vertices"] * 8 // 4096
        check("a big mesh's arrays are past the mmap threshold", array_pages * 4096 > 128 << 10, f)
        check("a new process's field reuses freed memory, not fresh pages",
              0 <= f["solve_page_faults"] < array_pages / 3, (f["solve_page_faults"], array_pages))

check.finish()
