"""``foliage import``: mesh files (pymeshlab) -> the USD tree layout the bakes read."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

# not importorskip: importing pymeshlab here, before numba starts its threads, would load pymeshlab's older TBB
# for the whole test process (scene.meshfile._pymeshlab explains)
if importlib.util.find_spec("pymeshlab") is None:
    pytest.skip("foliage import needs pymeshlab (a dependency: pip install -e .)", allow_module_level=True)

from foliage_tools.pipeline.import_model import ImportParams, run_import  # noqa: E402
from foliage_tools.scene.meshfile import CleanOptions  # noqa: E402
from tests.helpers.cli import foliage  # noqa: E402

#: A 2 x 0.5 leaf quad in the plane z = 1 (area 1, normal +z), written as two triangles with their own vertices
#: (as converters write them) and one duplicated triangle; a wood triangle in its own group, by relative indices.
QUAD_OBJ = """\
# a leaf card and a twig
o Card
usemtl LeafMaterial
v 0 0 1
v 2 0 1
v 2 0.5 1
v 0 0 1
v 2 0.5 1
v 0 0.5 1
f 1 2 3
f 4 5 6
f 4 5 6
o Twig
usemtl Bark
v 0 0 0
v 0.1 0 0
v 0 0 0.9
f -3/1 -2/1 -1/1
"""


def _mesh(stage, prim):
    from pxr import UsdGeom

    m = UsdGeom.Mesh(stage.GetPrimAtPath(prim))
    pts = np.asarray(m.GetPointsAttr().Get(), dtype=np.float64)
    counts = np.asarray(m.GetFaceVertexCountsAttr().Get())
    idx = np.asarray(m.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)
    assert np.all(counts == 3)
    return pts, idx


def test_an_obj_quad_imports_with_its_area_normal_and_classification(tmp_path):
    from pxr import Usd, UsdGeom

    from foliage_tools.scene.read import read_scene

    src = tmp_path / "card.obj"
    src.write_text(QUAD_OBJ)
    out = tmp_path / "card.usda"
    report = run_import(src, out, ImportParams(up_axis="Z", meters_per_unit=0.01))
    parts = {p["name"]: p for p in report.stats["parts"]}
    assert set(parts) == {"Card (LeafMaterial)", "Twig (Bark)"}
    assert parts["Card (LeafMaterial)"]["leaf"] and not parts["Twig (Bark)"]["leaf"]
    # the duplicate face is gone and the coincident corners are merged: one quad of 4 points
    assert parts["Card (LeafMaterial)"]["faces_read"] == 3 and parts["Card (LeafMaterial)"]["triangles"] == 2
    assert parts["Card (LeafMaterial)"]["points"] == 4
    stage = Usd.Stage.Open(str(out))
    assert UsdGeom.GetStageUpAxis(stage) == "Z" and UsdGeom.GetStageMetersPerUnit(stage) == 0.01
    assert stage.GetDefaultPrim().GetPath() == "/Tree" and Usd.ModelAPI(stage.GetDefaultPrim()).GetKind() == "component"
    leaf_prim = parts["Card (LeafMaterial)"]["prim"]
    pts, tris = _mesh(stage, leaf_prim)
    cross = np.cross(pts[tris[:, 1]] - pts[tris[:, 0]], pts[tris[:, 2]] - pts[tris[:, 0]])
    assert np.isclose(0.5 * np.linalg.norm(cross, axis=1).sum(), 1.0, rtol=1e-6)  # 2 x 0.5, exactly
    normals = cross / np.linalg.norm(cross, axis=1, keepdims=True)
    assert np.allclose(normals, [0, 0, 1], atol=1e-6)  # the winding of the file is kept
    assert stage.GetPrimAtPath(leaf_prim).HasAPI("FoliageLeafAPI")
    twig_pts, _ = _mesh(stage, parts["Twig (Bark)"]["prim"])
    assert np.allclose(sorted(map(tuple, twig_pts)), sorted([(0, 0, 0), (0.1, 0, 0), (0, 0, 0.9)]), atol=1e-6)
    # and it is what the bakes read: one leaf, one wood mesh
    scene, _ = read_scene(out)
    (proto,) = scene.prototypes
    assert proto.leaves.count == 1 and np.isclose(proto.leaves.areas.sum(), 1.0, rtol=1e-6)
    assert sorted(m.is_leaf for m in proto.meshes) == [False, True]


def _write_gltf(path: Path, meshes) -> None:
    """A minimal glTF 2.0 (embedded buffer) with one named node and mesh per entry (name, points, triangles)."""
    import base64

    buf, views, accessors, gl_meshes = b"", [], [], []
    for name, pts, tris in meshes:
        pts, tris = np.asarray(pts, np.float32), np.asarray(tris, np.uint32)
        for data, acc in ((pts, {"componentType": 5126, "count": len(pts), "type": "VEC3",
                                 "min": pts.min(0).tolist(), "max": pts.max(0).tolist()}),
                          (tris, {"componentType": 5125, "count": int(tris.size), "type": "SCALAR"})):
            views.append({"buffer": 0, "byteOffset": len(buf), "byteLength": data.nbytes})
            buf += data.tobytes()
            accessors.append({"bufferView": len(views) - 1, **acc})
        gl_meshes.append({"name": name, "primitives": [{"attributes": {"POSITION": len(accessors) - 2}, "indices": len(accessors) - 1}]})
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": list(range(len(meshes)))}],
           "nodes": [{"name": m["name"], "mesh": i} for i, m in enumerate(gl_meshes)], "meshes": gl_meshes,
           "accessors": accessors, "bufferViews": views,
           "buffers": [{"byteLength": len(buf), "uri": "data:application/octet-stream;base64," + base64.b64encode(buf).decode()}]}
    path.write_text(json.dumps(doc))


def test_a_gltf_imports_one_mesh_per_gltf_mesh_classified_by_name(tmp_path):
    from pxr import Usd

    square = ([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 3]])
    twig = ([[0, 0, 0], [0, 1, 0], [0.1, 1, 0]], [[0, 1, 2]])
    _write_gltf(tmp_path / "t.gltf", [("Needles", *square), ("Trunk", *twig)])
    r = foliage("import", tmp_path / "t.gltf", "-o", tmp_path / "t.usda", "--json")
    assert r.returncode == 0, r.stderr
    import jsonschema

    from tests.helpers.cli import REPORT_SCHEMA

    jsonschema.validate(json.loads(r.stdout), REPORT_SCHEMA)
    from tests.helpers.typed_json import assert_typed_stats

    assert_typed_stats(json.loads(r.stdout))
    parts = {p["name"]: p for p in json.loads(r.stdout)["stats"]["parts"]}
    assert parts["Needles"]["leaf"] and parts["Needles"]["triangles"] == 2 and not parts["Trunk"]["leaf"]
    stage = Usd.Stage.Open(str(tmp_path / "t.usda"))
    assert stage.GetMetadata("upAxis") == "Y"  # glTF is Y-up by its spec, and the default
    pts, _ = _mesh(stage, parts["Needles"]["prim"])
    assert np.allclose(sorted(map(tuple, pts)), sorted(map(tuple, square[0])))


def test_a_ply_of_cards_imports_with_all_leaves_and_simplify_spares_leaves(tmp_path):
    # two separate unit cards in an ASCII PLY: one unnamed mesh, leaves only by --all-leaves
    ply = tmp_path / "cards.ply"
    verts = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 2), (1, 0, 2), (1, 1, 2), (0, 1, 2)]
    faces = [(0, 1, 2), (0, 2, 3), (4, 5, 6), (4, 6, 7)]
    ply.write_text("ply\nformat ascii 1.0\nelement vertex 8\nproperty float x\nproperty float y\nproperty float z\n"
                   "element face 4\nproperty list uchar int vertex_indices\nend_header\n"
                   + "".join(f"{x} {y} {z}\n" for x, y, z in verts) + "".join(f"3 {a} {b} {c}\n" for a, b, c in faces))
    wood = run_import(ply, tmp_path / "w.usda", ImportParams())
    assert [p["leaf"] for p in wood.stats["parts"]] == [False] and any("--all-leaves" in w for w in wood.warnings)
    leaves = run_import(ply, tmp_path / "l.usda", ImportParams(all_leaves=True, clean=CleanOptions(simplify=0.5)))
    (p,) = leaves.stats["parts"]
    assert p["leaf"] and p["triangles"] == 4  # leaves are never simplified


def test_simplify_reduces_the_wood(tmp_path):
    # a finely tessellated wood tube (a grid rolled into a cylinder) next to a leaf card
    n, m = 24, 20
    th = np.linspace(0, 2 * np.pi, n, endpoint=False)
    z = np.linspace(0, 1, m)
    pts = [(0.05 * np.cos(a), 0.05 * np.sin(a), h) for h in z for a in th]
    lines = ["o trunk"] + [f"v {x} {y} {zz}" for x, y, zz in pts]
    for j in range(m - 1):
        for i in range(n):
            a, b = j * n + i + 1, j * n + (i + 1) % n + 1
            lines += [f"f {a} {b} {b + n}", f"f {a} {b + n} {a + n}"]
    lines += ["o leaf", "v 1 0 0", "v 1.1 0 0", "v 1.1 0.1 0", "f -3 -2 -1"]
    (tmp_path / "t.obj").write_text("\n".join(lines) + "\n")
    r = run_import(tmp_path / "t.obj", tmp_path / "t.usda", ImportParams(clean=CleanOptions(simplify=0.25)))
    parts = {p["name"]: p for p in r.stats["parts"]}
    assert parts["trunk"]["faces_read"] == 2 * n * (m - 1)
    assert parts["trunk"]["triangles"] <= 0.3 * parts["trunk"]["faces_read"]
    assert parts["leaf"]["triangles"] == 1


def test_unreadable_and_missing_files_exit_2_naming_the_file_and_write_nothing(tmp_path):
    bad = tmp_path / "broken.glb"
    bad.write_bytes(b"glTF\x02\x00\x00\x00 truncated")
    for src in (bad, tmp_path / "missing.obj"):
        out = tmp_path / "out.usda"
        r = foliage("import", src, "-o", out)
        assert r.returncode == 2, (src, r.stdout, r.stderr)
        assert src.name in r.stderr
        assert not out.exists() and not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
    empty = tmp_path / "empty.obj"
    empty.write_text("# nothing\nv 0 0 0\n")
    r = foliage("import", empty, "-o", tmp_path / "e.usda")
    assert r.returncode == 2 and "no faces" in r.stderr


def test_the_webots_oak_obj_imports_as_its_usd_conversion(tmp_path, oak):
    """The shared oak's OBJ gives the leaves, triangles and leaf area of its hand-made USD conversion."""
    from foliage_tools.scene.read import read_scene

    out = tmp_path / "oak.usda"
    run_import(oak.with_suffix(".obj"), out, ImportParams(up_axis="Z"))
    mine, theirs = read_scene(out)[0].prototypes[0], read_scene(oak)[0].prototypes[0]
    assert mine.leaves.count == theirs.leaves.count == 1831
    assert len(mine.triangles(leaves=False)) == len(theirs.triangles(leaves=False))
    assert np.isclose(mine.leaves.areas.sum(), theirs.leaves.areas.sum(), rtol=1e-6)


def test_an_import_in_the_process_leaves_numba_its_own_threading_layer(tmp_path):
    """A process that imports a mesh and then bakes (as `foliage batch` may) keeps numba's TBB layer, without warnings."""
    import subprocess
    import sys

    src = tmp_path / "card.obj"
    src.write_text(QUAD_OBJ)
    code = (
        "import warnings; warnings.simplefilter('error')\n"
        "import numpy as np, numba\n"
        "from foliage_tools.pipeline.import_model import ImportParams, run_import\n"
        f"run_import({str(src)!r}, {str(tmp_path / 'c.usda')!r}, ImportParams())\n"
        "@numba.njit(parallel=True)\n"
        "def total(a):\n"
        "    s = 0.0\n"
        "    for i in numba.prange(a.size):\n"
        "        s += a[i]\n"
        "    return s\n"
        "assert total(np.ones(1000)) == 1000\n"
        "print(numba.threading_layer())\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
