"""Write an imported model as a foliage tree asset: the USD layout ``scene.read`` expects (``foliage import``).

```
/Tree                      Xform, kind component, the default prim
/Tree/Materials/<name>     UsdPreviewSurface per source material (a leaf green or a bark brown)
/Tree/<part>               Mesh per part: triangles, extent, doubleSided, its material bound,
                           primvars:foliage:isLeaf (constant bool; leaves also get FoliageLeafAPI)
```

The classification is authored explicitly (``FoliageLeafAPI`` and the
``isLeaf`` flag outrank names in DESIGN.md section 3), so renaming a prim or
material later does not turn leaves into wood. Written atomically.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from foliage_tools.errors import OutputError
from foliage_tools.scene.atomic import atomic_outputs, check_name_fits, check_writable
from foliage_tools.scene.meshfile import Part
from foliage_tools.scene.schemas import LEAF_API, register

register()

from pxr import Kind, Sdf, Usd, UsdGeom, UsdShade, Vt  # noqa: E402

LEAF_COLOUR = (0.2, 0.45, 0.1)
BARK_COLOUR = (0.35, 0.25, 0.15)


def prim_name(name: str, taken: set[str]) -> str:
    """A valid, unique USD prim name for ``name`` (``leaves.001 (oak_leaf)`` -> ``leaves_001_oak_leaf``)."""
    base = re.sub(r"_+", "_", re.sub(r"[^A-Za-z0-9_]", "_", name)).strip("_") or "part"
    if base[0].isdigit():
        base = f"_{base}"
    out, k = base, 1
    while out in taken:
        out = f"{base}_{k}"
        k += 1
    taken.add(out)
    return out


def write_tree_asset(out: Path, parts: list[Part], *, up_axis: str, meters_per_unit: float, doc: str) -> list[str]:
    """Write ``parts`` as a tree asset at ``out`` (atomic); the mesh prim paths, in order."""
    out = Path(out)
    if out.suffix not in (".usda", ".usdc", ".usd"):
        raise OutputError(f"@{out}@: the output must be a USD layer (.usda, .usdc, .usd).")
    if out.parent.is_dir():
        check_name_fits(out)
    check_writable(out)
    paths = []
    with atomic_outputs([out]) as temps:
        stage = Usd.Stage.CreateInMemory()
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up_axis.upper() == "Y" else UsdGeom.Tokens.z)
        UsdGeom.SetStageMetersPerUnit(stage, float(meters_per_unit))
        root = UsdGeom.Xform.Define(stage, "/Tree")
        Usd.ModelAPI(root.GetPrim()).SetKind(Kind.Tokens.component)
        stage.SetDefaultPrim(root.GetPrim())
        stage.GetRootLayer().documentation = doc
        UsdGeom.Scope.Define(stage, "/Tree/Materials")
        materials: dict[tuple[str, bool], UsdShade.Material] = {}
        taken_mat: set[str] = set()
        taken = {"Materials"}
        for part in parts:
            key = (part.material or ("Leaf" if part.is_leaf else "Bark"), part.is_leaf)
            if key not in materials:
                materials[key] = _material(stage, f"/Tree/Materials/{prim_name(key[0], taken_mat)}", part.is_leaf)
            mesh = UsdGeom.Mesh.Define(stage, f"/Tree/{prim_name(part.name, taken)}")
            pts = np.asarray(part.points, dtype=np.float32)
            mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts))
            mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(part.triangles), 3, dtype=np.int32)))
            mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(part.triangles, dtype=np.int32).reshape(-1)))
            mesh.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.stack([pts.min(axis=0), pts.max(axis=0)])))
            mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
            mesh.CreateDoubleSidedAttr(True)
            flag = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("foliage:isLeaf", Sdf.ValueTypeNames.Bool, UsdGeom.Tokens.constant)
            flag.Set(bool(part.is_leaf))
            if part.is_leaf:
                mesh.GetPrim().ApplyAPI(LEAF_API)
            UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(materials[key])
            paths.append(str(mesh.GetPath()))
        if not stage.GetRootLayer().Export(str(temps[out])):
            raise OutputError(f"@{out}@: cannot be written.")
    return paths


def _material(stage: Usd.Stage, path: str, is_leaf: bool) -> UsdShade.Material:
    material = UsdShade.Material.Define(stage, path)
    shader = UsdShade.Shader.Define(stage, f"{path}/PreviewSurface")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(LEAF_COLOUR if is_leaf else BARK_COLOUR)
    shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.6 if is_leaf else 0.9)
    material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    return material
