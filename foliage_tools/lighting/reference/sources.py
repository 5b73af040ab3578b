"""The Monte Carlo reference's light sources: (origins, directions, weights) for k photons, or their first hits.

:class:`_SunSource` is the parallel sun beam, :class:`_SurfaceSunSource` its first hits drawn on the triangles
themselves, :class:`_PlacedSunSource` the same over placed prototypes, :class:`_SkySource` the uniform sky; what
each launches and with which power is section "Sources" of the package docstring
(:mod:`foliage_tools.lighting.reference`). :func:`_geometry` gives them the scene's bounds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from foliage_tools.geometry.instanced import InstancedRayScene, cofactors
from foliage_tools.lighting.reference.problem import Placements, ReferenceInputs
from foliage_tools.lighting.reference.sampling import _cosine_directions, _onb, _uniform_hemisphere

#: Relative enlargement of the sun rectangle / sky disc beyond the scene's
#: bounds, so that float rounding never lets geometry at the very edge miss.
_SOURCE_MARGIN = 1e-3


@dataclass(frozen=True)
class _Geometry:
    """What the sources need to know about the scene."""

    centre: np.ndarray  # (3,) bounding-box centre
    corners: np.ndarray  # (8, 3) bounding-box corners
    radius: float  # bounding-sphere radius (about centre), with margin
    period: tuple[float, float] | None
    cell_origin: tuple[float, float]
    z_top: float



def _geometry(inputs: ReferenceInputs, z_top: float | None, bounds: np.ndarray | None = None) -> _Geometry:
    tri = inputs.triangles
    if bounds is not None:
        lo, hi = bounds
    elif tri.shape[0]:
        lo = tri.reshape(-1, 3).min(axis=0)
        hi = tri.reshape(-1, 3).max(axis=0)
    else:
        lo = hi = np.zeros(3)
    centre = 0.5 * (lo + hi)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    half_diag = 0.5 * float(np.linalg.norm(hi - lo))
    radius = max(half_diag, 1e-30) * (1.0 + _SOURCE_MARGIN)
    return _Geometry(centre, corners, radius, inputs.period, inputs.cell_origin, z_top if z_top is not None else hi[2])


class _SunSource:
    """Parallel beam along -s, irradiance 1 perpendicular to it."""

    def __init__(self, geo: _Geometry, sun: np.ndarray, paths: int) -> None:
        self.sun = sun
        self.geo = geo
        if geo.period is None:
            u, v = _onb(sun[None, :])
            self.u, self.v = u[0], v[0]
            rel = geo.corners - geo.centre
            pu, pv, ps = rel @ self.u, rel @ self.v, rel @ sun
            margin = _SOURCE_MARGIN * max(2.0 * geo.radius, 1e-30)
            self.lo = np.array([pu.min(), pv.min()]) - margin
            self.hi = np.array([pu.max(), pv.max()]) + margin
            self.height = ps.max() + margin
            area = float(np.prod(self.hi - self.lo))
        else:
            px, py = geo.period
            area = float(sun[2]) * px * py  # horizontal irradiance μ0 on the cell
        self.power = area  # per channel
        # per photon: the whole beam's power; solve() divides the sun tallies by the paths traced
        self.weight = area

    def emit(self, rng: np.random.Generator, k: int):
        uv = rng.random((k, 2))
        if self.geo.period is None:
            a = self.lo + uv * (self.hi - self.lo)
            o = self.geo.centre + a[:, :1] * self.u + a[:, 1:] * self.v + self.height * self.sun
        else:
            px, py = self.geo.period
            o = np.empty((k, 3))
            o[:, 0] = self.geo.cell_origin[0] + uv[:, 0] * px
            o[:, 1] = self.geo.cell_origin[1] + uv[:, 1] * py
            o[:, 2] = self.geo.z_top
        d = np.broadcast_to(-self.sun, (k, 3)).copy()
        w = np.full((k, 3), self.weight)
        return o, d, w


class _SurfaceSunSource:
    """The sun beam's first hits, sampled on the surfaces themselves (splitting the beam at its first hit).

    The unscattered beam of irradiance 1 deposits, on a surface point x of a
    triangle with normal n, the power density |n·s| V(x) (V: 1 when the ray
    from x toward the sun escapes, else 0). Points are drawn on all triangles
    (leaves and wood) with density ∝ |n·s| per unit area -- systematic
    sampling over the triangles' projected areas A|n·s|, so a triangle's count
    is its expected count rounded up or down, and a uniform point inside --
    and each carries P / k (P = Σ A|n·s|); a shadow ray toward the sun keeps
    the points with V = 1 as first hits. Over the beam's rectangle this draws
    the same first hits as :class:`_SunSource` (an unbiased estimate of the
    same tallies) but spends no ray on photons that miss the foliage and
    spreads the first hits evenly over the lit leaves, which removes most of
    E_direct's noise and of the first-scattered source's.
    """

    def __init__(self, scene, triangles: np.ndarray, sun: np.ndarray, incident: float) -> None:
        self.scene = scene
        self.sun = sun
        self.tri = triangles
        normals = scene.normals
        self.cos = normals @ sun
        area = 0.5 * np.linalg.norm(np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]), axis=1)
        self.cum = np.cumsum(area * np.abs(self.cos))
        self.projected = float(self.cum[-1]) if self.cum.size else 0.0
        self.side = np.where(self.cos >= 0.0, 1.0, -1.0)[:, None] * normals
        self.offset = scene.offset_distance()
        self.power = incident  # per channel: the beam's power over the source area (energy balance)

    def first_hits(self, rng: np.random.Generator, k: int):
        """(tri, points, directions, weights) of the k drawn points that see the sun, and the weight per point."""
        weight = self.projected  # per point, like _SunSource: solve() divides by the paths traced
        if self.projected <= 0.0 or k == 0:
            return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), weight
        target = (np.arange(k) + rng.random()) * (self.projected / k)
        t = np.minimum(np.searchsorted(self.cum, target, side="right"), self.cum.size - 1)
        uv = rng.random((k, 2))
        fold = uv.sum(axis=1) > 1.0
        uv[fold] = 1.0 - uv[fold]
        v0 = self.tri[t, 0]
        p = v0 + uv[:, :1] * (self.tri[t, 1] - v0) + uv[:, 1:] * (self.tri[t, 2] - v0)
        origins = p + self.offset * self.side[t]
        seen = ~self.scene.occluded(origins, np.broadcast_to(self.sun, origins.shape))
        d = np.broadcast_to(-self.sun, (int(seen.sum()), 3)).copy()
        return t[seen], p[seen], d, np.full((d.shape[0], 3), weight), weight


class _PlacedSunSource:
    """:class:`_SurfaceSunSource` over placed prototypes, without a per-instance triangle list.

    The beam deposits on instance i the power P_i = Σ_t |a'_t·s| over its placed triangles, whose area
    vectors are a'_t = cof(A_i) a_t (a_t: the prototype triangle's area vector), so P_i = Σ_t |a_t·σ_i| with
    σ_i = cof(A_i)ᵀ s = det(A_i) A_i⁻¹ s. Points are drawn in two stages: instances by systematic sampling over
    P_i (each gets its expected count k P_i / P rounded up or down), then within the instance a prototype
    triangle with probability A_t / A (its share of the prototype's area) and a uniform point on it (uniform
    in the world too: the map is affine). A point's weight is P · A |n_t·σ_i| / P_i, the ratio of the target
    density (∝ |a'_t·s|) to the one drawn, so the expected power of each triangle is its |a'_t·s| V as in
    :class:`_SurfaceSunSource`; the weights average P per point and vary with |n·s| within an instance.
    """

    def __init__(self, scene: InstancedRayScene, placements: Placements, sun: np.ndarray, incident: float) -> None:
        self.scene = scene
        self.sun = sun
        self.pl = placements
        sigma = np.einsum("nji,j->ni", cofactors(placements.transforms[:, :3, :3]), sun)  # cof(A)ᵀ s
        self.sigma = sigma
        self.area_vec, self.cum_area = [], []
        proj = np.zeros(placements.n_instances)
        for p, tri in enumerate(placements.triangles):
            a = 0.5 * np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            self.area_vec.append(a)
            self.cum_area.append(np.cumsum(np.linalg.norm(a, axis=1)))
            sel = np.flatnonzero(placements.prototype_of == p)
            for chunk in np.array_split(sel, max(1, sel.size // 256)):
                if chunk.size and len(a):
                    proj[chunk] = np.abs(a @ sigma[chunk].T).sum(axis=0)
        self.proj = proj
        self.cum = np.cumsum(proj)
        self.projected = float(self.cum[-1]) if self.cum.size else 0.0
        self.offset = scene.offset_distance()
        self.power = incident

    def first_hits(self, rng: np.random.Generator, k: int):
        """((instance, triangle), points, directions, weights) of the drawn points that see the sun, and the mean weight."""
        weight = self.projected
        none = (np.zeros(0, np.int64), np.zeros(0, np.int64))
        if self.projected <= 0.0 or k == 0:
            return none, np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), weight
        target = (np.arange(k) + rng.random()) * (self.projected / k)
        inst = np.minimum(np.searchsorted(self.cum, target, side="right"), self.cum.size - 1)
        pick, uv = rng.random(k), rng.random((k, 2))
        fold = uv.sum(axis=1) > 1.0
        uv[fold] = 1.0 - uv[fold]
        tri = np.zeros(k, np.int64)
        local = np.zeros((k, 3))
        w = np.zeros(k)
        for p, (verts, a, cum) in enumerate(zip(self.pl.triangles, self.area_vec, self.cum_area)):
            sel = np.flatnonzero(self.pl.prototype_of[inst] == p)
            if sel.size == 0:
                continue
            t = np.minimum(np.searchsorted(cum, pick[sel] * cum[-1], side="right"), cum.size - 1)
            tri[sel] = t
            v0 = verts[t, 0]
            local[sel] = v0 + uv[sel, :1] * (verts[t, 1] - v0) + uv[sel, 1:] * (verts[t, 2] - v0)
            i = inst[sel]
            w[sel] = self.projected * cum[-1] * np.abs(np.einsum("kj,kj->k", a[t], self.sigma[i])) / (
                np.linalg.norm(a[t], axis=1) * self.proj[i])
        lin = self.pl.transforms[inst, :3, :3]
        p = np.einsum("kij,kj->ki", lin, local) + self.pl.transforms[inst, :3, 3]
        n = self.scene.world_normals(inst, tri)
        side = np.where(n @ self.sun >= 0.0, 1.0, -1.0)[:, None] * n
        origins = p + self.offset * side
        seen = ~self.scene.occluded(origins, np.broadcast_to(self.sun, origins.shape))
        d = np.broadcast_to(-self.sun, (int(seen.sum()), 3)).copy()
        return (inst[seen], tri[seen]), p[seen], d, np.repeat(w[seen, None], 3, axis=1), weight


class _SkySource:
    """Uniform radiance L over the hemisphere about ``up``."""

    def __init__(self, geo: _Geometry, up: np.ndarray, radiance: np.ndarray, paths: int) -> None:
        self.geo = geo
        self.up = up
        if geo.period is None:
            # ∫_hemisphere L dω over a disc πR² perpendicular to each direction
            self.power = radiance * 2.0 * math.pi * math.pi * geo.radius**2
        else:
            px, py = geo.period
            self.power = radiance * math.pi * px * py  # horizontal irradiance π L on the cell
        self.weight = self.power / paths if paths else np.zeros(3)

    def emit(self, rng: np.random.Generator, k: int):
        u = rng.random((k, 4))
        w = np.broadcast_to(self.weight, (k, 3)).copy()
        if self.geo.period is None:
            omega = _uniform_hemisphere(self.up, u[:, 0], u[:, 1])
            t1, t2 = _onb(omega)
            r = self.geo.radius * np.sqrt(u[:, 2])
            phi = 2.0 * math.pi * u[:, 3]
            o = (
                self.geo.centre
                + self.geo.radius * (1.0 + _SOURCE_MARGIN) * omega
                + (r * np.cos(phi))[:, None] * t1
                + (r * np.sin(phi))[:, None] * t2
            )
        else:
            omega = _cosine_directions(np.broadcast_to(self.up, (k, 3)), u[:, 0], u[:, 1])
            px, py = self.geo.period
            o = np.empty((k, 3))
            o[:, 0] = self.geo.cell_origin[0] + u[:, 2] * px
            o[:, 1] = self.geo.cell_origin[1] + u[:, 3] * py
            o[:, 2] = self.geo.z_top
        return o, -omega, w
