"""Read a ``UsdGeom.Camera`` from a stage into plain numbers (for ``foliage preview --camera``)."""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from foliage_tools.errors import InputError
from foliage_tools.scene.read import open_stage

from pxr import Usd, UsdGeom  # after scene.read, which registers the foliage schemas


@dataclass(frozen=True)
class UsdCameraParams:
    """The attributes of a ``UsdGeom.Camera`` at the default time, world transform included."""

    path: str
    transform: np.ndarray
    """(4, 4) float64 world-from-camera matrix, column-vector convention; the camera looks down its −Z, +Y up."""
    projection: str
    """``perspective`` or ``orthographic``."""
    focal_length: float
    horizontal_aperture: float
    vertical_aperture: float
    horizontal_aperture_offset: float
    vertical_aperture_offset: float
    """Apertures, offsets and focal length in tenths of a scene unit (USD's convention)."""
    clipping_range: tuple[float, float]
    """(near, far) distances in scene units."""


def list_cameras(stage: Usd.Stage) -> list[str]:
    return [str(p.GetPath()) for p in stage.Traverse() if p.IsA(UsdGeom.Camera)]


def read_camera(path: str | os.PathLike, prim_path: str) -> UsdCameraParams:
    """The camera at ``prim_path``; an :class:`InputError` naming the stage's cameras when it is not one."""
    stage = open_stage(path)
    if not prim_path.startswith("/"):
        raise InputError(f"@{path}@: --camera takes an absolute prim path such as </World/Camera>, got {prim_path!r}.")
    prim = stage.GetPrimAtPath(prim_path)
    cams = list_cameras(stage)
    listing = ", ".join(f"<{c}>" for c in cams[:10]) if cams else "none"
    if not prim:
        raise InputError(f"@{path}@: no prim at <{prim_path}>; cameras in the stage: {listing}.")
    if not prim.IsA(UsdGeom.Camera):
        raise InputError(f"@{path}@: <{prim_path}> is a {prim.GetTypeName() or 'typeless prim'}, not a Camera; cameras in the stage: {listing}.")
    cam = UsdGeom.Camera(prim)
    t = Usd.TimeCode.Default()
    world = np.array(UsdGeom.XformCache(t).GetLocalToWorldTransform(prim), dtype=np.float64).T  # USD row vectors -> column vectors

    def get(attr, default):
        v = attr.Get(t)
        return default if v is None else v

    clip = get(cam.GetClippingRangeAttr(), (1.0, 1000000.0))
    return UsdCameraParams(
        path=prim_path,
        transform=world,
        projection=str(get(cam.GetProjectionAttr(), "perspective")),
        focal_length=float(get(cam.GetFocalLengthAttr(), 50.0)),
        horizontal_aperture=float(get(cam.GetHorizontalApertureAttr(), 20.955)),
        vertical_aperture=float(get(cam.GetVerticalApertureAttr(), 15.2908)),
        horizontal_aperture_offset=float(get(cam.GetHorizontalApertureOffsetAttr(), 0.0)),
        vertical_aperture_offset=float(get(cam.GetVerticalApertureOffsetAttr(), 0.0)),
        clipping_range=(float(clip[0]), float(clip[1])),
    )
