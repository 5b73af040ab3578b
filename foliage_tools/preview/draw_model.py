"""What the previewer draws, in plain arrays: meshes, prototypes and their instances, the sun and sky, the
ground disc, and the frames that come back. No GL: this module imports without moderngl.

:class:`DrawScene` holds the triangles of each prototype (one :class:`DrawMesh`
per material, with the baked terms the methods add: E_scattered per corner,
s_max per corner with τ per prototype for ``smax``, the LB relighting bases)
and the world-from-prototype matrices of its instances; :class:`Lighting`,
:class:`Ground` and :class:`Frame` are what :class:`~foliage_tools.preview.renderer.Renderer`
takes and gives back per frame. :func:`face_normals` and :func:`sky_directions`
are the GL-free geometry the renderer derives from them. Nothing of USD or
files (:meth:`DrawScene.from_scene` takes an already read
:class:`~foliage_tools.scene.model.Scene`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from collections.abc import Mapping

import numpy as np

from foliage_tools.preview.camera import bounds_corners
from foliage_tools.scene.model import Scene

RGB = tuple[float, float, float]


# -- what is drawn -----------------------------------------------------------------


@dataclass(frozen=True)
class DrawMesh:
    """Triangles of one material of one prototype, un-indexed (3 corners per triangle)."""

    corners: np.ndarray
    """(3T, 3) float32 corner positions in prototype space, stage units."""
    leaf: bool
    """Leaves (two-sided, translucent) or wood (opaque)."""
    indirect: Mapping[str, np.ndarray] = field(default_factory=dict)
    """Per method name: (3T, 3) float32 scattered irradiance E_scattered at each corner (leaves only)."""
    smax: np.ndarray | None = None
    """(3T, 8) float32 s_max(P, ω_j) of each corner's leaf (boulanger2008 eq. (5.28) order), stage
    units: the ``smax`` method evaluates Boulanger's model from it in the vertex shader."""
    lb_bases: np.ndarray | None = None
    """(18, 3T, 3) float32 scattered irradiance of each LB Kronecker base B_1..B_18 at each corner
    (steele2010 sec. 3.1): the ``lb`` method then relights every instance for the current sun
    from the three bases that bracket it in the instance's frame, instead of ``indirect["lb"]``."""

    def __post_init__(self) -> None:
        if self.corners.ndim != 2 or self.corners.shape[1] != 3 or self.corners.shape[0] % 3:
            raise ValueError(f"corners must be (3T, 3), got {self.corners.shape}")
        if self.smax is not None:
            if self.smax.shape != (self.corners.shape[0], 8):
                raise ValueError(f"smax has shape {self.smax.shape}, expected ({self.corners.shape[0]}, 8)")
            if not np.all(np.isfinite(self.smax)) or np.any(self.smax < 0):
                raise ValueError("smax must be finite and >= 0")
        for name, values in self.indirect.items():
            if values.shape != self.corners.shape:
                raise ValueError(f"indirect term {name!r} has shape {values.shape}, corners {self.corners.shape}")
        if self.lb_bases is not None and self.lb_bases.shape != (18,) + self.corners.shape:
            raise ValueError(f"lb_bases has shape {self.lb_bases.shape}, expected (18, {self.corners.shape[0]}, 3)")

    @property
    def triangle_count(self) -> int:
        return self.corners.shape[0] // 3


@dataclass(frozen=True)
class DrawPrototype:
    meshes: tuple[DrawMesh, ...]
    transforms: np.ndarray
    """(N, 4, 4) float64 world-from-prototype matrices (column-vector convention), one per instance."""
    tau: float | None = None
    """Optical thickness τ of the tree (``foliage:tau``), 1/stage unit; needed with ``DrawMesh.smax``."""
    smax_up: np.ndarray | None = None
    """(3,) the up axis in the prototype's frame that s_max was computed with (it orients the ω_j of
    eq. (5.28)); default: the stage's up axis as seen by the first instance."""

    def sample_directions(self, up: np.ndarray) -> np.ndarray:
        """(8, 3) boulanger2008 eq. (5.28) directions in the prototype's frame, as ``foliage smax`` used them."""
        from foliage_tools.geometry.sun import to_prototype_space
        from foliage_tools.lighting.envelope import sample_directions

        local_up = self.smax_up
        if local_up is None:
            local_up = to_prototype_space(np.asarray(up, dtype=np.float64), self.transforms[0]) if len(self.transforms) else up
        return sample_directions(np.asarray(local_up, dtype=np.float64))

    def world_bounds(self) -> np.ndarray | None:
        pts = [m.corners for m in self.meshes if len(m.corners)]
        if not pts or not len(self.transforms):
            return None
        allp = np.concatenate(pts).astype(np.float64)
        box = bounds_corners(np.stack([allp.min(axis=0), allp.max(axis=0)]))
        world = np.einsum("nij,kj->nki", self.transforms[:, :3, :3], box) + self.transforms[:, None, :3, 3]
        world = world.reshape(-1, 3)
        return np.stack([world.min(axis=0), world.max(axis=0)])


@dataclass(frozen=True)
class DrawScene:
    """Everything the renderer draws, in plain arrays."""

    prototypes: tuple[DrawPrototype, ...]
    up: np.ndarray
    """(3,) unit up axis of the stage."""

    @property
    def triangle_count(self) -> int:
        """Triangles drawn per pass, instances included."""
        return sum(m.triangle_count * len(p.transforms) for p in self.prototypes for m in p.meshes)

    @property
    def instance_count(self) -> int:
        return sum(len(p.transforms) for p in self.prototypes)

    @property
    def methods(self) -> set[str]:
        names = {k for p in self.prototypes for m in p.meshes for k in m.indirect}
        if any(m.smax is not None and p.tau is not None for p in self.prototypes for m in p.meshes):
            names.add("smax")
        if any(m.lb_bases is not None for p in self.prototypes for m in p.meshes):
            names.add("lb")
        return names

    def bounds(self) -> np.ndarray:
        """(2, 3) world-space box around all instances (of each prototype's box corners)."""
        boxes = [b for b in (p.world_bounds() for p in self.prototypes) if b is not None]
        if not boxes:
            raise ValueError("the scene has no geometry to draw")
        b = np.stack(boxes)
        return np.stack([b[:, 0].min(axis=0), b[:, 1].max(axis=0)])

    @classmethod
    def from_scene(
        cls,
        scene: Scene,
        indirect: Mapping[str, Mapping[str, np.ndarray]] | None = None,
        smax: Mapping[str, tuple[float, Mapping[str, np.ndarray]]] | None = None,
        lb_bases: Mapping[str, np.ndarray] | None = None,
    ) -> DrawScene:
        """Merge each prototype's meshes into one leaf and one wood :class:`DrawMesh`.

        ``indirect`` maps a method name to ``{mesh prim path: (T, 3, 3) or (3T, 3)
        E_scattered per triangle corner}``; leaf meshes a method does not cover get 0.
        ``smax`` maps a prototype path to ``(τ, {leaf mesh path: (3T, 8) s_max per corner})``;
        a prototype's leaves are drawn with the ``smax`` method only when all its leaf
        meshes have s_max. ``lb_bases`` maps a leaf mesh path to its (18, 3T, 3) relighting
        bases (:attr:`DrawMesh.lb_bases`); used when all leaf meshes of a prototype have them.
        """
        indirect = indirect or {}
        smax = smax or {}
        lb_bases = lb_bases or {}
        protos = []
        for k, proto in enumerate(scene.prototypes):
            transforms = np.array([inst.transform for inst in scene.instances if inst.prototype == k], dtype=np.float64).reshape(-1, 4, 4)
            if not len(transforms):
                continue
            meshes = []
            for leaf in (True, False):
                parts = [m for m in proto.meshes if m.is_leaf == leaf and len(m.triangles)]
                if not parts:
                    continue
                corners = np.concatenate([m.points[m.triangles].reshape(-1, 3) for m in parts]).astype(np.float32)
                terms = {}
                for method, per_mesh in indirect.items():
                    if not leaf or not any(m.path in per_mesh for m in parts):
                        continue
                    terms[method] = np.concatenate(
                        [
                            np.asarray(per_mesh[m.path], dtype=np.float32).reshape(-1, 3)
                            if m.path in per_mesh
                            else np.zeros((3 * len(m.triangles), 3), np.float32)
                            for m in parts
                        ]
                    )
                baked = smax.get(proto.path)
                corner_smax = None
                if leaf and baked is not None and all(m.path in baked[1] for m in parts):
                    corner_smax = np.concatenate([np.asarray(baked[1][m.path], dtype=np.float32).reshape(-1, 8) for m in parts])
                corner_lb = None
                if leaf and parts and all(m.path in lb_bases for m in parts):
                    corner_lb = np.concatenate([np.asarray(lb_bases[m.path], dtype=np.float32) for m in parts], axis=1)
                meshes.append(DrawMesh(corners=corners, leaf=leaf, indirect=terms, smax=corner_smax, lb_bases=corner_lb))
            tau = smax[proto.path][0] if proto.path in smax else None
            protos.append(DrawPrototype(meshes=tuple(meshes), transforms=transforms, tau=tau))
        return cls(prototypes=tuple(protos), up=scene.up)


@dataclass(frozen=True)
class Lighting:
    """Sun and sky, in the units of DESIGN.md section 3."""

    sun_direction: np.ndarray
    """(3,) unit vector toward the sun."""
    sun_irradiance: RGB = (1.0, 1.0, 1.0)
    """Irradiance on a plane perpendicular to the sun (1 per channel by the DESIGN contract, times the sun's colour)."""
    sky_radiance: RGB = (0.0, 0.0, 0.0)
    """Uniform radiance of the sky hemisphere (a dome light's intensity × colour)."""

    def __post_init__(self) -> None:
        d = np.asarray(self.sun_direction, dtype=np.float64)
        if d.shape != (3,) or not np.all(np.isfinite(d)) or not np.linalg.norm(d) > 0:
            raise ValueError(f"sun direction must be a finite non-zero 3-vector, got {self.sun_direction!r}")
        for name in ("sun_irradiance", "sky_radiance"):
            v = getattr(self, name)
            if len(v) != 3 or not all(math.isfinite(c) and c >= 0 for c in v):
                raise ValueError(f"{name} must be three finite values >= 0, got {v!r}")


@dataclass(frozen=True)
class Ground:
    """A Lambertian ground disc through ``point``, perpendicular to the up axis.

    Tessellated in rings whose radii grow geometrically from ``detail`` to
    ``radius``: the sky visibility is evaluated per vertex, so the mesh is fine
    under the trees, where their occlusion varies, and coarse far away.
    """

    point: np.ndarray
    radius: float
    detail: float | None = None
    """Radius of the innermost ring [default: radius / 1000]."""
    rings: int = 48
    segments: int = 64

    @classmethod
    def under(cls, bounds: np.ndarray, up: np.ndarray, *, extent: float = 50.0) -> Ground:
        """Under the lowest point of ``bounds``, ``extent`` times the largest side of ``bounds`` in radius.

        Large enough that its far edge lies close to the horizon in any orbit
        view (a small ground would show its edge as a false horizon).
        """
        lo, hi = np.asarray(bounds, dtype=np.float64)
        centre = (lo + hi) / 2
        point = centre - up * (centre @ up) + up * float(lo @ up)
        size = max(float(np.ptp(np.asarray(bounds), axis=0).max()), 1e-6)
        return cls(point=point, radius=extent * size, detail=size / 32)

    def bounds(self, up: np.ndarray) -> np.ndarray:
        flat = self.radius * (1 - np.abs(up))
        return np.stack([self.point - flat, self.point + flat])

    def corners(self, up: np.ndarray) -> np.ndarray:
        """(3T, 3) float64 triangle corners of the disc, counter-clockwise seen from above."""
        a = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        u = np.cross(up, a)
        u /= np.linalg.norm(u)
        v = np.cross(up, u)  # (u, v, up) is right-handed: increasing angle turns counter-clockwise about up
        detail = self.detail or self.radius / 1000
        radii = detail * (self.radius / detail) ** (np.arange(self.rings) / (self.rings - 1))
        phi = np.linspace(0.0, 2 * np.pi, self.segments + 1)
        ring = np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v  # (S+1, 3), closed
        pts = self.point + radii[:, None, None] * ring[None]  # (R, S+1, 3)
        centre = np.broadcast_to(self.point, (self.segments, 3))
        fan = np.stack([centre, pts[0, :-1], pts[0, 1:]], axis=1)
        a0, a1 = pts[:-1, :-1], pts[:-1, 1:]  # inner ring
        b0, b1 = pts[1:, :-1], pts[1:, 1:]  # outer ring
        quads = np.concatenate([np.stack([a0, b0, b1], axis=2), np.stack([a0, b1, a1], axis=2)]).reshape(-1, 3, 3)
        return np.concatenate([fan, quads]).reshape(-1, 3)


@dataclass(frozen=True)
class Frame:
    """One rendered image, top row first."""

    radiance: np.ndarray
    """(H, W, 3) float32 linear RGB radiance toward the camera, premultiplied by ``alpha`` (background 0)."""
    alpha: np.ndarray
    """(H, W) float32 coverage of any geometry (tree and ground), antialiased."""
    tree: np.ndarray
    """(H, W) float32 coverage of the tree (leaves and wood) only."""
    sky: RGB
    """Radiance of the sky behind the geometry: ``radiance + (1 - alpha) * sky`` is the picture over the sky."""
    seconds: float
    """Wall time of the draw and read-back."""


# -- geometry derived from it --------------------------------------------------------


def face_normals(corners: np.ndarray) -> np.ndarray:
    """(3T, 3) float32: each triangle's right-handed unit normal at its three corners (0 for degenerate ones)."""
    tri = np.asarray(corners, dtype=np.float64).reshape(-1, 3, 3)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
    return np.repeat(n, 3, axis=0).astype(np.float32)


def sky_directions(count: int, up: np.ndarray) -> np.ndarray:
    """(count, 3) unit directions spread evenly (in solid angle) over the hemisphere around ``up``.

    A Fibonacci spiral: equal-area bands in cos(zenith) (the area element of a
    sphere is d(cos θ) dφ), azimuths stepped by the golden angle. Deterministic.
    """
    if count == 0:
        return np.zeros((0, 3))
    i = np.arange(count) + 0.5
    cos_t = 1.0 - i / count  # uniform in (0, 1): equal solid angle per direction
    sin_t = np.sqrt(1.0 - cos_t**2)
    phi = i * math.pi * (3.0 - math.sqrt(5.0))
    a = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(up, a)
    u /= np.linalg.norm(u)
    v = np.cross(up, u)
    return (sin_t * np.cos(phi))[:, None] * u + (sin_t * np.sin(phi))[:, None] * v + cos_t[:, None] * up
