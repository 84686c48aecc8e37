#!/usr/bin/env python3
"""GIFTI end to end: the bundled mesh written as a .surf.gii by nibabel (an
independent writer, GZipBase64Binary as FreeSurfer and HCP write it) goes
through geodesicd info, build, field and matrix; the field written as a
.func.gii metric, read with nibabel, equals the field of the same mesh given
as .obj; a truncated .surf.gii is refused by name, without a crash.
Usage: offline_gifti_test.py BUILD_BIN_DIR SOURCE_DIR"""
import json
import os
import sys
import tempfile

import nibabel as nib
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from checklist import Checklist  # noqa: E402
from geodesicd_runner import geodesicd_runner, read_obj  # noqa: E402

bin_dir, src = sys.argv[1], sys.argv[2]
check = Checklist()
run = geodesicd_runner(bin_dir)


def write_surf_gii(path, vertices, faces, encoding="GZipBase64Binary"):
    points = nib.gifti.GiftiDataArray(vertices.astype(np.float32), "NIFTI_INTENT_POINTSET",
                                      "NIFTI_TYPE_FLOAT32", encoding=encoding)
    triangles = nib.gifti.GiftiDataArray(faces.astype(np.int32), "NIFTI_INTENT_TRIANGLE",
                                         "NIFTI_TYPE_INT32", encoding=encoding)
    nib.save(nib.gifti.GiftiImage(darrays=[points, triangles]), path)


with tempfile.TemporaryDirectory() as work:
    vertices, faces = read_obj(os.path.join(src, "data", "spot.obj"))
    # The .obj twin holds the float32 coordinates the .surf.gii holds, in
    # full (%.17g), so that both files describe the same mesh to the bit.
    vertices = vertices.astype(np.float32).astype(np.float64)
    obj = os.path.join(work, "spot32.obj")
    with open(obj, "w") as f:
        f.writelines(f"v {x:.17g} {y:.17g} {z:.17g}\n" for x, y, z in vertices)
        f.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces)
    gii = os.path.join(work, "spot.surf.gii")
    write_surf_gii(gii, vertices, faces)

    info = json.loads(run("info", gii, "--json").stdout)
    check("info reads the .surf.gii: counts",
          info["vertices"] == len(vertices) and info["faces"] == len(faces), info)
    check("info names the format gii", info.get("format") == "gii", info.get("format"))

    graphs = {}
    for mesh in (gii, obj):
        graphs[mesh] = os.path.join(work, os.path.basename(mesh) + ".dgg")
        run("build", mesh, "--eps", "1e-2", "--out", graphs[mesh])
    check("build writes a graph for the .surf.gii", os.path.getsize(graphs[gii]) > 0)

    def field(mesh, out, *sources):
        specs = [a for s in sources for a in ("--source", s)]
        run("field", "--mesh", mesh, "--graph", graphs[mesh], *specs, "--out", out)

    sources = ("v:0", "v:1500")
    field(gii, os.path.join(work, "gii.func.gii"), *sources)
    field(gii, os.path.join(work, "gii.f64"), *sources)
    field(obj, os.path.join(work, "obj.f64"), *sources)
    from_obj = np.fromfile(os.path.join(work, "obj.f64"), dtype="<f8")
    from_gii = np.fromfile(os.path.join(work, "gii.f64"), dtype="<f8")
    check("field on the .surf.gii equals the .obj's, bit for bit",
          from_obj.size == len(vertices) and np.array_equal(from_gii, from_obj),
          f"{np.sum(from_gii != from_obj)} differ")

    metric = nib.load(os.path.join(work, "gii.func.gii"))
    arrays = metric.darrays
    check("the metric is one float32 NIFTI_INTENT_SHAPE array",
          len(arrays) == 1 and arrays[0].data.dtype == np.float32 and
          arrays[0].intent == nib.nifti1.intent_codes["NIFTI_INTENT_SHAPE"],
          [(a.data.dtype, a.intent) for a in arrays])
    check("the metric is the .obj's field rounded to float32",
          len(arrays) == 1 and np.array_equal(arrays[0].data, from_obj.astype(np.float32)))

    matrix = os.path.join(work, "m.npy")
    run("matrix", "--mesh", gii, "--graph", graphs[gii], "--sources", "v:0", "v:1500",
        "--targets", "all", "--dtype", "float64", "--out", matrix)
    rows = np.load(matrix)
    single = os.path.join(work, "v0.f64")
    field(obj, single, "v:0")
    check("matrix --mesh x.surf.gii: row of v:0 is the .obj's field",
          rows.shape == (2, len(vertices)) and
          np.array_equal(rows[0], np.fromfile(single, dtype="<f8")), rows.shape)

    # Another encoding nibabel writes: plain Base64Binary.
    b64 = os.path.join(work, "b64.surf.gii")
    write_surf_gii(b64, vertices, faces, encoding="Base64Binary")
    info = json.loads(run("info", b64, "--json").stdout)
    check("Base64Binary surface reads", info["vertices"] == len(vertices), info)

    # nibabel's defaults, as a pipeline saves numpy arrays without naming a
    # type: float64 points and int64 triangles.
    defaults = os.path.join(work, "defaults.surf.gii")
    nib.save(nib.gifti.GiftiImage(darrays=[
        nib.gifti.GiftiDataArray(vertices, "NIFTI_INTENT_POINTSET"),
        nib.gifti.GiftiDataArray(faces.astype(np.int64), "NIFTI_INTENT_TRIANGLE")]), defaults)
    written = [a.data.dtype for a in nib.load(defaults).darrays]
    graphs[defaults] = graphs[gii]  # the same mesh, so the same graph
    field(defaults, os.path.join(work, "defaults.f64"), *sources)
    from_defaults = np.fromfile(os.path.join(work, "defaults.f64"), dtype="<f8")
    check("a float64 / int64 .surf.gii (nibabel's defaults) gives the .obj's field, bit for bit",
          written == [np.float64, np.int64] and np.array_equal(from_defaults, from_obj), written)

    truncated = os.path.join(work, "torn.surf.gii")
    with open(gii, "rb") as f, open(truncated, "wb") as out:
        out.write(f.read()[: os.path.getsize(gii) // 2])
    r = run("info", truncated, expect_ok=False)
    check("a truncated .surf.gii is refused by name, without a crash",
          r.returncode > 0 and "torn.surf.gii" in r.stderr, (r.returncode, r.stderr))

check.finish()
