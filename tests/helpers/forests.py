"""Forests of instances: stages built for a test, a bake of them, and where pxr (not the code under test) puts the
instances, their leaves and the volumes placed over them."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from foliage_tools.lighting.optics import parse_leaf_optics
from foliage_tools.params import DensityParams
from foliage_tools.pipeline.density import run_density
from foliage_tools.pipeline.direct import DirectChoice
from foliage_tools.pipeline.lb import LBBakeParams, run_lb
from tests.conftest import cards_mesh, write_mesh_stage

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def mixed_forest(tmp_path: Path) -> Path:
    """3 native instances of one asset + a PointInstancer with 2 prototypes, 5 instances, one masked."""
    from pxr import Gf, Usd, UsdGeom, Vt

    write_mesh_stage(tmp_path / "asset.usda", {"Leaves": {**cards_mesh([(0, 0, 1), (0.3, 0, 1)]), "isLeaf": True}})
    stage = Usd.Stage.CreateNew(str(tmp_path / "forest.usda"))
    UsdGeom.SetStageUpAxis(stage, "Z")
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.Xform.Define(stage, "/World")
    for i in range(3):
        x = UsdGeom.Xform.Define(stage, f"/World/Tree_{i}")
        x.GetPrim().GetReferences().AddReference("./asset.usda")
        x.GetPrim().SetInstanceable(True)
        x.AddTranslateOp().Set(Gf.Vec3d(10.0 * i, 0, 0))
    pi = UsdGeom.PointInstancer.Define(stage, "/World/Grove")
    a = UsdGeom.Xform.Define(stage, "/World/Grove/Protos/A")
    a.GetPrim().GetReferences().AddReference("./asset.usda")
    a.AddTranslateOp().Set(Gf.Vec3d(0, 0, 100))  # prototype root transform: applied per instance
    b = UsdGeom.Xform.Define(stage, "/World/Grove/Protos/B")
    leaves = UsdGeom.Mesh.Define(stage, "/World/Grove/Protos/B/Leaves")
    m = cards_mesh([(0, 0, 2)])
    leaves.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(m["points"].astype(np.float32)))
    leaves.CreateFaceVertexCountsAttr(m["counts"])
    leaves.CreateFaceVertexIndicesAttr(m["indices"])
    pi.CreatePrototypesRel().SetTargets([a.GetPath(), b.GetPath()])
    pi.CreateProtoIndicesAttr([0, 1, 0, 1, 0])
    pi.CreatePositionsAttr([Gf.Vec3f(0, 50 + i, 0) for i in range(5)])
    pi.DeactivateIds([1])  # masked: must not shift the others' prototypes
    stage.GetRootLayer().Save()
    return tmp_path / "forest.usda"


def moved_bundled_forest(work: Path) -> Path:
    """The bundled forest (4 native instances, 12 point-instanced copies of one instanceable tree) copied into
    ``work``, its default prim moved and turned: a placement that forgot that transform lands beside the trees."""
    from pxr import Gf, Usd, UsdGeom

    work.mkdir(parents=True, exist_ok=True)
    for name in ("forest_small.usda", "tree_small.usda"):
        shutil.copy(EXAMPLES / name, work / name)
    stage = Usd.Stage.Open(str(work / "forest_small.usda"))
    world = UsdGeom.Xformable(stage.GetPrimAtPath("/World"))
    world.AddTranslateOp().Set(Gf.Vec3d(6.0, -3.0, 0.5))
    world.AddRotateZOp().Set(30.0)
    stage.GetRootLayer().Save()
    return work / "forest_small.usda"


def bake_density_lb(forest: Path, out_dir: Path, resolution: int = 16) -> Path:
    """density, then lb on its output (the lb layer carries the density grids into its own .vdb)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    run_density(forest, out_dir / "f.density.usda", DensityParams(resolution=resolution))
    run_lb(out_dir / "f.density.usda", out_dir / "f.lb.usda",
           # no gather: it traces every instance, so the forest lattice (its .forest.vdb) would not be solved
           LBBakeParams(optics=parse_leaf_optics(None), resolution=resolution, direct=DirectChoice(mode="volume"), gather=0))
    return out_dir / "f.lb.usda"


def leaf_points_per_instance(stage) -> dict[str, np.ndarray]:
    """World positions of every leaf-mesh point of each instance, from the instance prims' own transforms (pxr)."""
    from pxr import Gf, Usd, UsdGeom

    t = Usd.TimeCode.Default()
    xf = UsdGeom.XformCache(t)

    def leaf_points(root):
        # (points of the leaf mesh, mesh-to-root matrix), through the instance proxies below an instanceable root
        for prim in Usd.PrimRange(root, Usd.TraverseInstanceProxies()):
            if prim.IsA(UsdGeom.Mesh) and prim.GetName() == "Leaves":
                rel, _ = xf.ComputeRelativeTransform(prim, root)
                yield np.array(UsdGeom.Mesh(prim).GetPointsAttr().Get(), dtype=np.float64), rel

    def apply(points, m: Gf.Matrix4d) -> np.ndarray:  # Gf is row-vector
        m = np.array(m)
        return points @ m[:3, :3] + m[3, :3]

    out = {}
    for n in range(4):
        inst = stage.GetPrimAtPath(f"/World/Trees/Tree_{n:02d}")
        world = xf.GetLocalToWorldTransform(inst)
        out[str(inst.GetPath())] = np.concatenate([apply(p, rel * world) for p, rel in leaf_points(inst)])
    pi = UsdGeom.PointInstancer(stage.GetPrimAtPath("/World/Grove"))
    proto = stage.GetPrimAtPath(pi.GetPrototypesRel().GetTargets()[0])
    pi_world = xf.GetLocalToWorldTransform(pi.GetPrim())
    placed = pi.ComputeInstanceTransformsAtTime(t, t, UsdGeom.PointInstancer.IncludeProtoXform)
    meshes = list(leaf_points(proto))
    for i, m in enumerate(placed):
        out[f"/World/Grove[{i}]"] = np.concatenate([apply(p, rel * m * pi_world) for p, rel in meshes])
    return out


def instance_transforms(stage) -> dict[str, np.ndarray]:
    """World-from-prototype (4, 4) of each instance, column-vector convention, from the instance prims (pxr)."""
    from pxr import Usd, UsdGeom

    t = Usd.TimeCode.Default()
    xf = UsdGeom.XformCache(t)
    out = {f"/World/Trees/Tree_{n:02d}": np.array(xf.GetLocalToWorldTransform(stage.GetPrimAtPath(f"/World/Trees/Tree_{n:02d}"))).T
           for n in range(4)}
    pi = UsdGeom.PointInstancer(stage.GetPrimAtPath("/World/Grove"))
    pi_world = xf.GetLocalToWorldTransform(pi.GetPrim())
    for i, m in enumerate(pi.ComputeInstanceTransformsAtTime(t, t, UsdGeom.PointInstancer.IncludeProtoXform)):
        out[f"/World/Grove[{i}]"] = np.array(m * pi_world).T
    return out


def placed_volumes(stage) -> dict[str, object]:
    """foliage:instance -> the Volume prim placed over it, as a DCC traverses the stage (class prims skipped)."""
    from pxr import UsdVol

    out = {}
    for prim in stage.Traverse():
        if prim.IsA(UsdVol.Volume) and prim.GetName() == "FoliageLighting":
            out[prim.GetParent().GetAttribute("foliage:instance").Get()] = prim
    return out
