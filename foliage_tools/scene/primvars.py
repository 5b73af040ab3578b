"""Read baked per-leaf primvars back from a stage, as plain arrays (for the previewer and checks).

The bakes write their results on the leaf meshes (DESIGN.md section 3), e.g.
``primvars:foliage:lbIndirect`` (color3f[], vertex) or
``primvars:foliage:ref:scattered`` (color3f[], uniform). This module only
reads them: values are flattened (indexed primvars expanded) and returned
with their interpolation, in the mesh's authored point/face order.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from foliage_tools.errors import InputError
from foliage_tools.scene.read import open_stage

from pxr import UsdGeom  # after scene.read, which registers the foliage schemas


@dataclass(frozen=True)
class PrimvarValues:
    """One primvar of one mesh."""

    mesh: str
    """Prim path of the mesh."""
    name: str
    """Primvar name without the ``primvars:`` namespace, e.g. ``foliage:lbIndirect``."""
    values: np.ndarray
    """(N, k) float64 flattened values: k = 3 for colours, the element size for arrays of tuples."""
    interpolation: str
    """``constant``, ``uniform``, ``vertex``, ``varying`` or ``faceVarying``."""
    element_size: int


def read_mesh_primvars(path: str | os.PathLike, names: list[str], mesh_paths: list[str]) -> dict[str, dict[str, PrimvarValues]]:
    """``{name: {mesh path: values}}`` for every listed mesh that has the primvar authored.

    Names are given without ``primvars:`` (``foliage:lbIndirect``). Meshes that
    lack a primvar are absent from its dict; a missing mesh prim is an
    :class:`InputError` (the caller took the paths from the same stage).
    """
    stage = open_stage(path)
    out: dict[str, dict[str, PrimvarValues]] = {name: {} for name in names}
    for mesh_path in dict.fromkeys(mesh_paths):
        prim = stage.GetPrimAtPath(mesh_path)
        if not prim:
            raise InputError(f"@{path}@: mesh <{mesh_path}> is missing when re-opening the stage; was the file changed meanwhile?")
        api = UsdGeom.PrimvarsAPI(prim)
        for name in names:
            pv = api.GetPrimvar(name)
            if not pv or not pv.HasAuthoredValue():
                continue
            raw = pv.ComputeFlattened()
            if raw is None:
                continue
            try:
                values = np.asarray(raw, dtype=np.float64)
            except (TypeError, ValueError):
                raise InputError(
                    f"@{path}@: <{mesh_path}> primvars:{name} has type {pv.GetTypeName()}, not numbers; re-run the bake that writes it."
                ) from None
            element_size = int(pv.GetElementSize() or 1)
            if values.ndim == 0:
                values = values.reshape(1, 1)
            elif values.ndim == 1:
                values = values.reshape(-1, element_size) if element_size > 1 and values.size % element_size == 0 else values[:, None]
            out[name][mesh_path] = PrimvarValues(
                mesh=mesh_path, name=name, values=values, interpolation=str(pv.GetInterpolation()), element_size=element_size
            )
    return out


def read_attribute(path: str | os.PathLike, name: str, prim_paths: list[str]) -> dict[str, object]:
    """``{prim path: value}`` of attribute ``name`` (e.g. ``foliage:tau``) for every listed prim; None where
    the prim or the attribute is missing or has no value."""
    stage = open_stage(path)
    out: dict[str, object] = {}
    for prim_path in dict.fromkeys(prim_paths):
        prim = stage.GetPrimAtPath(prim_path)
        attr = prim.GetAttribute(name) if prim else None
        out[prim_path] = attr.Get() if attr else None
    return out


def read_volume(path: str | os.PathLike, volume: str, field_names: list[str], attribute_names: list[str]) -> tuple[dict, dict]:
    """``({field name: resolved file or None}, {attribute name: value or None})`` of the volume prim ``volume``,
    reading the stage once: each ``OpenVDBAsset`` child's file and the volume's own attributes."""
    from pxr import UsdVol

    stage = open_stage(path)
    files: dict[str, str | None] = {}
    for name in field_names:
        prim = stage.GetPrimAtPath(f"{volume}/{name}")
        asset = UsdVol.OpenVDBAsset(prim).GetFilePathAttr().Get() if prim and prim.IsA(UsdVol.OpenVDBAsset) else None
        files[name] = (asset.resolvedPath or None) if asset is not None else None
    prim = stage.GetPrimAtPath(volume)
    attrs = {}
    for name in attribute_names:
        attr = prim.GetAttribute(name) if prim else None
        attrs[name] = attr.Get() if attr else None
    return files, attrs
