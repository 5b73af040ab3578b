"""Issue #17: bakes of tree_small, the Webots oak and the bundled forest imported into Blender (``bpy``, Blender as a
Python module) arrive whole.

Blender runs in its own venv (bpy pins its own Python and numpy), in a
subprocess running ``tests/blender/usd_import_probe.py``: ``make setup-bpy``
makes ``.venv-bpy/`` (README, "Blender"), or point ``FOLIAGE_BPY_PYTHON`` at
the Python of any venv that has ``bpy``. Without one, the test is skipped and
says so. Marker ``dcc``: ``make test-dcc`` (run by ``.ci/run`` after ``make test``) installs the venv first.
"""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

from foliage_tools.lighting.optics import parse_leaf_optics
from foliage_tools.pipeline.bake import BakeParams, run_bake
from foliage_tools.pipeline.direct import DirectChoice

pytestmark = pytest.mark.dcc

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "examples" / "tree_small.usda"
PROBE = REPO / "tests" / "blender" / "usd_import_probe.py"


def bpy_python() -> Path | None:
    """The Python of the bpy venv: $FOLIAGE_BPY_PYTHON, else the repository's .venv-bpy (``make setup-bpy``)."""
    env = os.environ.get("FOLIAGE_BPY_PYTHON")
    candidates = [Path(env)] if env else [REPO / ".venv-bpy" / "bin" / "python"]
    return next((c for c in candidates if c.is_file()), None)


NO_BPY = ("no Blender Python: `make setup-bpy` (a venv with `pip install bpy` at .venv-bpy), or set "
          "FOLIAGE_BPY_PYTHON to the python of a venv that has bpy")


def _probe(python: Path, final: Path, cwd: Path) -> dict:
    """Blender's default USD import of ``final``, as the probe script reports it."""
    r = subprocess.run([str(python), str(PROBE), str(final)], capture_output=True, text=True, timeout=300, cwd=cwd)
    lines = [line for line in r.stdout.splitlines() if line.startswith("PROBE")]
    assert r.returncode == 0 and lines, f"Blender probe failed ({python}):\n{r.stdout[-2000:]}\n{r.stderr[-2000:]}"
    return json.loads(lines[-1][len("PROBE"):])


def _bake_and_import(tree: Path, tmp_path_factory) -> tuple[Path, dict]:
    python = bpy_python()
    if python is None:
        pytest.skip(NO_BPY)
    out = tmp_path_factory.mktemp("blender") / "out"
    report = run_bake(tree, out, BakeParams(optics=parse_leaf_optics(None), resolution=12, direct=DirectChoice(mode="volume")))
    final = Path(report.stats["result"])
    return final, _probe(python, final, tmp_path_factory.mktemp("blender-cwd"))


@pytest.fixture(scope="module")
def blender_import(tmp_path_factory):
    return _bake_and_import(EXAMPLE, tmp_path_factory)


def _objects(probe, kind=None):
    return {o["name"]: o for o in probe["objects"] if kind is None or o["type"] == kind}


def test_the_volume_arrives_with_every_grid_from_one_file_and_no_stray_objects(blender_import):
    import pyopenvdb
    from pxr import Usd, UsdVol

    final, probe = blender_import
    volumes = _objects(probe, "VOLUME")
    assert set(volumes) == {"FoliageLighting"}, "the volume is imported by default (purpose default)"
    vol = volumes["FoliageLighting"]
    stage = Usd.Stage.Open(str(final))
    fields = UsdVol.Volume(stage.GetPrimAtPath("/Tree/FoliageLighting")).GetFieldPaths()
    assert {g["name"] for g in vol["grids"]} == set(fields) == {
        "density", "woodFraction", "sppGFactor", "sppDepth", "sppThickness", "lbSun"}
    assert Path(vol["filepath"]).resolve() == (final.parent / "tree_small.lb.vdb").resolve()
    for g in vol["grids"]:
        assert g["data_type"] == ("VECTOR_FLOAT" if g["name"] == "lbSun" else "FLOAT"), g["name"]
        # Blender's index-to-object matrix is the grid's own transform (voxel size, voxel centres)
        t = pyopenvdb.read(str(final.parent / "tree_small.lb.vdb"), g["name"]).transform
        m = np.asarray(g["matrix"])
        h = np.linalg.norm(np.subtract(t.indexToWorld((1, 0, 0)), t.indexToWorld((0, 0, 0))))
        assert np.allclose(np.diag(m)[:3], h, rtol=1e-6) and np.allclose(m[:3, 3], t.indexToWorld((0, 0, 0)), atol=1e-6)
    # the OpenVDBAsset prims no longer arrive as Empties
    empties = set(_objects(probe, "EMPTY"))
    assert not empties & set(fields), empties
    assert {"Leaves", "Wood"} <= set(_objects(probe, "MESH"))


def test_per_direction_primvars_arrive_with_their_values(blender_import):
    from pxr import Usd, UsdGeom

    final, probe = blender_import
    leaves = _objects(probe, "MESH")["Leaves"]
    stage = Usd.Stage.Open(str(final))
    pv = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/Tree/Leaves"))
    faces = leaves["faces"]
    for base in ("smax", "attenuation"):
        packed = np.asarray(pv.GetPrimvar(f"foliage:{base}").Get(), dtype=np.float32).reshape(faces, 8)
        for k in range(8):
            attr = leaves["attributes"][f"foliage:{base}{k}"]
            assert attr["domain"] == "FACE" and attr["data_type"] == "FLOAT", (base, k)
            assert np.array_equal(np.asarray(attr["values"], dtype=np.float32), packed[:, k]), (base, k)
    assert np.ptp(packed) > 0
    lb = np.asarray(pv.GetPrimvar("foliage:lb:scattered").Get(), dtype=np.float32)
    assert np.allclose(leaves["attributes"]["foliage:lb:scattered"]["values"], lb, rtol=1e-6, atol=0)


def test_the_bake_metadata_arrives_as_custom_properties(blender_import):
    from pxr import Usd

    final, probe = blender_import
    stage = Usd.Stage.Open(str(final))
    vol_prim = stage.GetPrimAtPath("/Tree/FoliageLighting")
    props = _objects(probe, "VOLUME")["FoliageLighting"]["data_props"]
    assert np.isclose(props["foliage:voxelSize"], vol_prim.GetAttribute("foliage:voxelSize").Get(), rtol=1e-6)
    assert list(props["foliage:resolution"]) == list(vol_prim.GetAttribute("foliage:resolution").Get())
    assert props["foliage:method"] == "lb" and props["foliage:version"] == vol_prim.GetAttribute("foliage:version").Get()
    tree = _objects(probe)["Tree"]["props"]
    assert np.isclose(tree["foliage:tau"], stage.GetPrimAtPath("/Tree").GetAttribute("foliage:tau").Get(), rtol=1e-6)
    assert tree["foliage:smax:path"] in ("reference", "fast")
    assert np.allclose(tree["foliage:lb:sunDirection"], stage.GetPrimAtPath("/Tree").GetAttribute("foliage:lb:sunDirection").Get())


@pytest.fixture(scope="module")
def blender_forest(tmp_path_factory):
    """The bundled forest (4 native instances, 12 point-instanced copies of one instanceable tree) under a moved and
    turned default prim, baked (density, lb) and imported into Blender."""
    from tests.helpers.forests import bake_density_lb, moved_bundled_forest

    python = bpy_python()
    if python is None:
        pytest.skip(NO_BPY)
    work = tmp_path_factory.mktemp("blender-forest")
    final = bake_density_lb(moved_bundled_forest(work / "in"), work / "out")
    return final, _probe(python, final, tmp_path_factory.mktemp("blender-cwd"))


def test_a_native_instance_forest_volume_arrives_over_each_tree(blender_forest):
    """One Blender volume per instance, each with the prototype's grids from its one file, placed where pxr puts that
    instance's leaves (computed from the instance prims, not from the bake's placements)."""
    from pxr import Usd

    from tests.helpers.forests import instance_transforms, leaf_points_per_instance, placed_volumes

    final, probe = blender_forest
    stage = Usd.Stage.Open(str(final))
    leaves, transforms = leaf_points_per_instance(stage), instance_transforms(stage)
    placing = {str(prim.GetParent().GetName()): inst for inst, prim in placed_volumes(stage).items()}
    volumes = [o for o in probe["objects"] if o["type"] == "VOLUME" and o["name"].startswith("FoliageLighting")]

    def instance(o):
        # Blender merges an Xform with one child into the child (its default "merge parent Xform"): the volume
        # object then carries the placing prim's transform and its foliage:instance; unmerged, its parent does
        return o["props"].get("foliage:instance") or placing.get(o["parent"])

    # 16 placed volumes, no prototype-space one at the origin (the class is not imported)
    assert sorted(map(instance, volumes)) == sorted(leaves), [(o["name"], o["parent"], o["props"]) for o in volumes]
    for o in volumes:
        inst = instance(o)
        assert {g["name"] for g in o["grids"]} == {"density", "woodFraction", "lbSun"}, inst
        assert Path(o["filepath"]).resolve() == final.with_suffix(".vdb").resolve(), inst
        # the volume object stands where the instance stands: its world matrix is the instance's world-from-prototype
        # (Blender's Z-up and metres are the stage's, so no axis or unit conversion comes between)
        np.testing.assert_allclose(np.asarray(o["matrix_world"]), transforms[inst], atol=1e-5, err_msg=inst)
        # and its grids' world box (axis-aligned, rounded out to OpenVDB's 8-voxel leaf nodes) holds the leaves
        box = np.asarray(o["world_bound_box"])
        lo, hi = box.min(axis=0), box.max(axis=0)
        assert np.all(leaves[inst] >= lo - 1e-3) and np.all(leaves[inst] <= hi + 1e-3), inst


def test_the_oak_arrives_with_every_per_leaf_value_and_grid(oak, tmp_path_factory):
    """A third-party tree (the Webots oak: its own prim names, two wood meshes): every per-face ``foliage:`` primvar
    (float or colour) pxr reads on its leaf mesh arrives in Blender with the same values, and the volume with every
    field."""
    from pxr import Usd, UsdGeom, UsdVol

    final, probe = _bake_and_import(oak, tmp_path_factory)
    stage = Usd.Stage.Open(str(final))
    meshes = _objects(probe, "MESH")
    assert {"leaves_0", "wood_1", "wood_2"} <= set(meshes)
    leaves = meshes["leaves_0"]
    pv = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/Tree/leaves_0"))
    compared = []
    for primvar in pv.GetPrimvars():
        name = primvar.GetPrimvarName()
        if not name.startswith("foliage:") or primvar.GetElementSize() != 1:
            continue
        values = np.asarray(primvar.Get())
        if values.dtype.kind != "f" or values.ndim > 2 or primvar.GetInterpolation() != UsdGeom.Tokens.uniform:
            continue
        attr = leaves["attributes"].get(name)
        assert attr is not None, f"{name} did not arrive"
        assert attr["domain"] == "FACE" and len(attr["values"]) == leaves["faces"] == len(values), name
        np.testing.assert_allclose(attr["values"], values, rtol=1e-6, atol=0, err_msg=name)
        compared.append(name)
    # the bake's per-leaf scattered light of each method and the 8 per-direction s_max at least
    assert {"foliage:lb:scattered", "foliage:spp:scattered", *(f"foliage:smax{k}" for k in range(8))} <= set(compared)
    volumes = _objects(probe, "VOLUME")
    assert set(volumes) == {"FoliageLighting"}
    fields = UsdVol.Volume(stage.GetPrimAtPath("/Tree/FoliageLighting")).GetFieldPaths()
    assert {g["name"] for g in volumes["FoliageLighting"]["grids"]} == set(fields)
