"""Cameras for the previewer: orbit cameras that frame bounds, and cameras from USD parameters.

Conventions
-----------
* Matrices are 4×4 float64 in the column-vector convention of
  :mod:`foliage_tools.scene.model`: ``p_clip = projection @ view @ [x, y, z, 1]``.
* The view matrix maps world space to camera space, where the camera looks
  down −Z with +Y up (OpenGL and ``UsdGeom.Camera`` alike).
* Projections map the view frustum to OpenGL's clip space (NDC z in [−1, 1]).
* Pixel coordinates: x to the right, y *down*, (0, 0) the top-left corner of
  the top-left pixel, so a pixel's centre is at (i + 0.5, j + 0.5) — the
  numpy row/column layout of the images the renderer returns.
* Angles (DESIGN.md section 3): azimuth in degrees counter-clockwise about the
  up axis from +X (toward +Y in a Z-up stage, toward −Z in a Y-up stage),
  elevation in degrees above the horizon.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from foliage_tools.errors import UsageError
from foliage_tools.geometry.sun import angles_from_direction, direction_from_angles, horizon_frame  # noqa: F401  (re-exported)

UP_AXES = ("Y", "Z")

# GfCamera::APERTURE_UNIT: USD apertures and focal lengths are in tenths of a
# scene unit; only orthographic cameras need the absolute scale.
USD_APERTURE_UNIT = 0.1


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(4, 4) view matrix of a camera at ``eye`` looking at ``target``, ``up`` roughly up in the image.

    Raises ``ValueError`` when ``eye == target`` or the view direction is parallel to ``up``.
    """
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    back = eye - target
    n = np.linalg.norm(back)
    if n == 0.0:
        raise ValueError("look_at: eye and target coincide")
    back /= n
    right = np.cross(up, back)
    rn = np.linalg.norm(right)
    if rn < 1e-9:
        raise ValueError("look_at: view direction is parallel to the up vector")
    right /= rn
    true_up = np.cross(back, right)
    view = np.eye(4)
    view[0, :3], view[1, :3], view[2, :3] = right, true_up, back
    view[:3, 3] = -view[:3, :3] @ eye
    return view


def frustum(left: float, right: float, bottom: float, top: float, near: float, far: float) -> np.ndarray:
    """(4, 4) OpenGL perspective projection (glFrustum): the window is given on the near plane."""
    p = np.zeros((4, 4))
    p[0, 0] = 2.0 * near / (right - left)
    p[1, 1] = 2.0 * near / (top - bottom)
    p[0, 2] = (right + left) / (right - left)
    p[1, 2] = (top + bottom) / (top - bottom)
    p[2, 2] = -(far + near) / (far - near)
    p[2, 3] = -2.0 * far * near / (far - near)
    p[3, 2] = -1.0
    return p


def perspective(fovy: float, aspect: float, near: float, far: float) -> np.ndarray:
    """(4, 4) symmetric perspective projection; ``fovy`` is the vertical field of view in degrees."""
    if not (0.0 < fovy < 180.0):
        raise UsageError(f"the field of view must be between 0 and 180 degrees, got {fovy}.")
    t = near * math.tan(math.radians(fovy) / 2.0)
    return frustum(-t * aspect, t * aspect, -t, t, near, far)


def orthographic(left: float, right: float, bottom: float, top: float, near: float, far: float) -> np.ndarray:
    """(4, 4) OpenGL orthographic projection (glOrtho)."""
    p = np.eye(4)
    p[0, 0] = 2.0 / (right - left)
    p[1, 1] = 2.0 / (top - bottom)
    p[2, 2] = -2.0 / (far - near)
    p[0, 3] = -(right + left) / (right - left)
    p[1, 3] = -(top + bottom) / (top - bottom)
    p[2, 3] = -(far + near) / (far - near)
    return p


@dataclass(frozen=True)
class Camera:
    """A view and a projection for an image of ``width`` × ``height`` pixels."""

    view: np.ndarray
    """(4, 4) float64 world -> camera space."""
    projection: np.ndarray
    """(4, 4) float64 camera -> clip space."""
    width: int
    height: int
    near: float
    far: float

    @property
    def position(self) -> np.ndarray:
        """(3,) camera position in world space."""
        return np.linalg.inv(self.view)[:3, 3]

    @property
    def forward(self) -> np.ndarray:
        """(3,) unit viewing direction in world space."""
        return -self.view[2, :3] / np.linalg.norm(self.view[2, :3])

    @property
    def orthographic(self) -> bool:
        return bool(self.projection[3, 3] == 1.0)

    def view_projection(self) -> np.ndarray:
        return self.projection @ self.view

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates of world points.

        Returns
        -------
        pixels : (N, 2) float64
            x right, y down, in pixels (module convention).
        w : (N,) float64
            Clip-space w: the distance in front of the camera (> 0 when visible) for
            perspective cameras, 1 for orthographic ones.
        """
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        clip = np.c_[p, np.ones(len(p))] @ self.view_projection().T
        w = clip[:, 3]
        ndc = clip[:, :2] / w[:, None]
        px = np.empty((len(p), 2))
        px[:, 0] = (ndc[:, 0] + 1.0) * 0.5 * self.width
        px[:, 1] = (1.0 - ndc[:, 1]) * 0.5 * self.height
        return px, w


def bounds_corners(bounds: np.ndarray) -> np.ndarray:
    """(8, 3) corners of a (2, 3) min/max box."""
    lo, hi = np.asarray(bounds, dtype=np.float64)
    return np.array([[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])


def check_size(width: int, height: int) -> None:
    if not (isinstance(width, (int, np.integer)) and isinstance(height, (int, np.integer))):
        raise UsageError(f"the image size must be whole pixels, got {width!r}x{height!r}.")
    if not (1 <= width <= 16384 and 1 <= height <= 16384):
        raise UsageError(f"the image size must be between 1 and 16384 pixels per side, got {width}x{height}.")


def orbit_camera(
    bounds: np.ndarray,
    *,
    width: int,
    height: int,
    up_axis: str,
    azimuth: float = 0.0,
    elevation: float = 15.0,
    distance: float | None = None,
    fovy: float = 35.0,
    margin: float = 1.05,
    clip_bounds: np.ndarray | None = None,
) -> Camera:
    """A perspective camera on a sphere around the centre of ``bounds``, looking at it.

    Parameters
    ----------
    bounds : (2, 3) array
        World-space min/max box to frame; the camera looks at its centre.
    azimuth, elevation : float
        Degrees, DESIGN.md convention: where the camera sits as seen from the target.
    distance : float, optional
        From the target, stage units. Default: the smallest distance at which all
        8 corners of ``bounds`` fit in the image, times ``margin`` in image extent.
    fovy : float
        Vertical field of view, degrees.
    clip_bounds : (2, 3) array, optional
        A box that must lie between the near and far planes (e.g. bounds plus the
        ground plane); default ``bounds``.
    """
    check_size(width, height)
    if not (-90.0 <= elevation <= 90.0):
        raise UsageError(f"--elevation must be between -90 and 90 degrees, got {elevation}.")
    if not (1.0 <= fovy <= 170.0):
        raise UsageError(f"the field of view must be between 1 and 170 degrees, got {fovy}.")
    if distance is not None and not (math.isfinite(distance) and distance > 0.0):
        raise UsageError(f"--distance must be a positive number of stage units, got {distance}.")
    bounds = np.asarray(bounds, dtype=np.float64)
    target = bounds.mean(axis=0)
    x_axis, y_axis, up = horizon_frame(up_axis)
    back = direction_from_angles(azimuth, elevation, up_axis)
    horizontal = math.cos(math.radians(azimuth)) * x_axis + math.sin(math.radians(azimuth)) * y_axis
    # Looking straight down (up), the image's up is the limit of the tilted
    # views: away from (toward) the camera's azimuth.
    up_hint = up if abs(back @ up) < 0.999 else -np.sign(back @ up) * horizontal
    rot = look_at(back, np.zeros(3), up_hint)[:3, :3]  # rows: right, up, back
    aspect = width / height
    ty = math.tan(math.radians(fovy) / 2.0)
    tx = ty * aspect
    rel = (bounds_corners(bounds) - target) @ rot.T  # corners in camera axes, target at the origin
    if distance is None:
        # a corner at (x, y, z) is in the image when |x| <= tx (D - z) and |y| <= ty (D - z)
        need = np.maximum(rel[:, 2] + margin * np.abs(rel[:, 0]) / tx, rel[:, 2] + margin * np.abs(rel[:, 1]) / ty)
        distance = float(max(need.max(), 1e-6 * max(1.0, float(np.abs(bounds).max()))))
    eye = target + distance * back
    view = look_at(eye, target, up_hint)
    clip = np.asarray(bounds if clip_bounds is None else clip_bounds, dtype=np.float64)

    def depths(box: np.ndarray) -> np.ndarray:  # > 0 in front of the camera
        return -(np.c_[bounds_corners(box), np.ones(8)] @ view.T)[:, 2]

    # The near plane stays well in front of the framed bounds, and within a tenth of
    # the distance so that a ground plane running under the camera is not cut off at
    # the bottom of the image; never closer than 1e-3 of the distance (depth precision).
    nearest = float(depths(bounds).min())
    near = max(1e-3 * distance, min(0.95 * nearest, 0.1 * distance)) if nearest > 0 else 1e-3 * distance
    far = max(float(depths(clip).max()), float(depths(bounds).max())) * 1.05
    far = max(far, near * 2.0)
    return Camera(view=view, projection=perspective(fovy, aspect, near, far), width=width, height=height, near=near, far=far)


def usd_camera_size(horizontal_aperture: float, vertical_aperture: float, width: int = 1024) -> tuple[int, int]:
    """An image size with the aspect ratio of a USD camera's aperture, ``width`` pixels wide."""
    if not (horizontal_aperture > 0 and vertical_aperture > 0):
        raise UsageError("the camera's apertures must be positive.")
    return width, max(1, round(width * vertical_aperture / horizontal_aperture))


def camera_from_usd(
    *,
    transform: np.ndarray,
    projection: str,
    focal_length: float,
    horizontal_aperture: float,
    vertical_aperture: float,
    horizontal_aperture_offset: float = 0.0,
    vertical_aperture_offset: float = 0.0,
    clipping_range: tuple[float, float],
    width: int,
    height: int,
    name: str = "the camera",
) -> Camera:
    """The camera described by ``UsdGeom.Camera`` attributes (plain numbers, see ``scene/camera_read.py``).

    ``transform`` is the camera's (4, 4) world matrix (column-vector convention);
    scale in it is ignored, as ``GfFrustum`` does. When the image aspect ratio
    differs from the aperture's, the window is widened in one direction so the
    whole authored aperture stays visible (Hydra's ``CameraUtilFit`` policy).
    """
    check_size(width, height)
    if projection not in ("perspective", "orthographic"):
        raise UsageError(f"{name}: projection must be perspective or orthographic, got {projection!r}.")
    if not (horizontal_aperture > 0 and vertical_aperture > 0):
        raise UsageError(f"{name}: horizontalAperture and verticalAperture must be positive, got {horizontal_aperture}, {vertical_aperture}.")
    if projection == "perspective" and not focal_length > 0:
        raise UsageError(f"{name}: focalLength must be positive, got {focal_length}.")
    near, far = (float(v) for v in clipping_range)
    if not (0 < near < far and math.isfinite(far)):
        raise UsageError(f"{name}: clippingRange must satisfy 0 < near < far, got ({near}, {far}).")
    m = np.asarray(transform, dtype=np.float64)
    axes = m[:3, :3] / np.linalg.norm(m[:3, :3], axis=0)  # drop scale, keep rotation
    world = np.eye(4)
    world[:3, :3], world[:3, 3] = axes, m[:3, 3]
    view = np.linalg.inv(world)
    h_ap, v_ap = float(horizontal_aperture), float(vertical_aperture)
    aspect = width / height
    if aspect > h_ap / v_ap:
        h_ap = v_ap * aspect
    else:
        v_ap = h_ap / aspect
    cx, cy = float(horizontal_aperture_offset), float(vertical_aperture_offset)
    if projection == "perspective":
        s = near / float(focal_length)  # window on the near plane; aperture units cancel
        proj = frustum((cx - h_ap / 2) * s, (cx + h_ap / 2) * s, (cy - v_ap / 2) * s, (cy + v_ap / 2) * s, near, far)
    else:
        u = USD_APERTURE_UNIT
        proj = orthographic((cx - h_ap / 2) * u, (cx + h_ap / 2) * u, (cy - v_ap / 2) * u, (cy + v_ap / 2) * u, near, far)
    return Camera(view=view, projection=proj, width=width, height=height, near=near, far=far)
