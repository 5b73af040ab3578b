"""Shared fixtures: small hand-made USD stages, paths to the third-party assets, a seeded rng."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
# FOLIAGE_TEST_ASSETS: where they are when the checkout is not beside ../shared (a git worktree elsewhere)
ASSETS = Path(os.environ.get("FOLIAGE_TEST_ASSETS") or REPO.parent / "shared" / "assets")
OAK = ASSETS / "webots_oak" / "oak.usda"


def sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20261123)


@pytest.fixture
def oak() -> Path:
    if not OAK.exists():
        pytest.skip(f"third-party assets not present at {ASSETS}")
    return OAK


def card(center, size=0.1, normal_axis=2) -> tuple[np.ndarray, list[int]]:
    """A square leaf card: 4 points and one quad, perpendicular to ``normal_axis``."""
    c = np.asarray(center, dtype=float)
    h = size / 2
    a, b = [i for i in range(3) if i != normal_axis]
    pts = np.tile(c, (4, 1))
    for k, (da, db) in enumerate(((-h, -h), (h, -h), (h, h), (-h, h))):
        pts[k, a] += da
        pts[k, b] += db
    return pts, [4]


def write_mesh_stage(path: Path, meshes: dict[str, dict], *, up_axis="Z", meters_per_unit=1.0) -> Path:
    """Write a stage with meshes under /Tree. Each mesh: points, counts, indices, optional isLeaf/api/purpose/visibility."""
    from foliage_tools.scene.schemas import register

    register()
    from pxr import Sdf, Usd, UsdGeom, Vt

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, up_axis)
    UsdGeom.SetStageMetersPerUnit(stage, meters_per_unit)
    root = UsdGeom.Xform.Define(stage, "/Tree")
    stage.SetDefaultPrim(root.GetPrim())
    for name, m in meshes.items():
        mesh = UsdGeom.Mesh.Define(stage, f"/Tree/{name}")
        mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.asarray(m["points"], dtype=np.float32)))
        mesh.CreateFaceVertexCountsAttr(list(map(int, m["counts"])))
        mesh.CreateFaceVertexIndicesAttr(list(map(int, m["indices"])))
        if "isLeaf" in m:
            UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("foliage:isLeaf", Sdf.ValueTypeNames.Bool, UsdGeom.Tokens.constant).Set(m["isLeaf"])
        if m.get("api"):
            mesh.GetPrim().ApplyAPI("FoliageLeafAPI")
        if m.get("purpose"):
            mesh.CreatePurposeAttr(m["purpose"])
        if m.get("invisible"):
            mesh.CreateVisibilityAttr(UsdGeom.Tokens.invisible)
    stage.GetRootLayer().Save()
    return path


def cards_mesh(centers, size=0.1, normal_axis=2) -> dict:
    """Several cards in one mesh, each with its own 4 vertices."""
    pts, counts, idx = [], [], []
    for i, c in enumerate(centers):
        p, _ = card(c, size, normal_axis)
        pts.append(p)
        counts.append(4)
        idx.extend(range(4 * i, 4 * i + 4))
    return {"points": np.concatenate(pts), "counts": counts, "indices": idx}


@pytest.fixture
def simple_tree(tmp_path) -> Path:
    """Two leaf cards (isLeaf) and a wood triangle: the smallest valid tree."""
    leaves = cards_mesh([(0.0, 0.0, 1.0), (0.5, 0.0, 1.2)])
    leaves["isLeaf"] = True
    wood = {"points": [(0, 0, 0), (0.05, 0, 0), (0, 0, 1.0)], "counts": [3], "indices": [0, 1, 2], "isLeaf": False}
    return write_mesh_stage(tmp_path / "tree.usda", {"Leaves": leaves, "Trunk": wood})
