"""The path loop of one batch of the Monte Carlo reference.

:class:`_Tracer` holds what every batch shares (the ray scene, the surfaces' optics) and traces k photons of a
source bounce by bounce; :func:`_process_hits` (numba, without the GIL) tallies one bounce and draws each photon's
event; :class:`_Tally` is a batch's sums. The weights and events are section "Scattering and weights" of the
package docstring (:mod:`foliage_tools.lighting.reference`), the tallies section "Tallies".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from foliage_tools.geometry.instanced import InstancedRayScene
from foliage_tools.geometry.rays import PeriodicRayScene, RayScene
from foliage_tools.lighting.reference.problem import ReferenceInputs
from foliage_tools.lighting.reference.sources import _PlacedSunSource, _SurfaceSunSource

#: Tally categories (index into the per-leaf incidence tallies).
_SUN_DIRECT, _SUN_SCATTERED, _SKY_DIRECT, _SKY_SCATTERED = range(4)


@njit(nogil=True, cache=True)
def _process_hits(
    tri, pts, d, w, scattered, leaf_of_tri, normals, refl, trans, absp, u, offset, first_category, count_hits, w_min,
    incidence, absorbed, absorbed_wood, escaped, hits, o_out, d_out, w_out,
):
    """Tally one bounce of k photons and draw their events; survivors are written compactly.

    For photon i: a miss adds w[i] to ``escaped``; a hit on a leaf adds w[i]
    to ``incidence[leaf * 4 + category]`` (category: first_category + scattered),
    then, while Σ_c w_c ≥ ``w_min``, W(1 - r - t) is deposited and reflect or
    transmit is drawn with probabilities ∝ Σ_c w_c r_c, Σ_c w_c t_c; below it,
    one of reflect / transmit / absorb is drawn with probabilities
    proportional to Σ_c w_c r_c, Σ_c w_c t_c, Σ_c w_c (1 - r_c - t_c) (package
    docstring), using u[i, 0]; a survivor gets a cosine-distributed direction
    from u[i, 1:3] (Malley's method, Duff et al. 2017 basis) about the normal on
    the side it leaves to, and starts ``offset`` off the surface on that side.
    Runs without the GIL so that batches on several threads overlap.
    Returns the number of survivors.
    """
    k = tri.shape[0]
    m = 0
    for i in range(k):
        j = tri[i]
        if j < 0:
            for c in range(3):
                escaped[c] += w[i, c]
            continue
        leaf = leaf_of_tri[j]
        if leaf >= 0:
            key = leaf * 4 + first_category + (1 if scattered[i] else 0)
            for c in range(3):
                incidence[key, c] += w[i, c]
            if count_hits:
                hits[leaf] += 1
        a_r = 0.0
        a_t = 0.0
        a_a = 0.0
        for c in range(3):
            a_r += w[i, c] * refl[j, c]
            a_t += w[i, c] * trans[j, c]
            a_a += w[i, c] * absp[j, c]
        total = a_r + a_t + a_a
        if total <= 0.0:
            # nothing left to carry: the weight underflowed to zero in every channel (a bounce off a subnormal
            # reflectance); the event draw below would divide 0 by 0, and there is nothing to deposit
            continue
        if total >= w_min:
            # expected-value absorption: deposit W(1 - r - t) and go on with the rest
            for c in range(3):
                dep = w[i, c] * absp[j, c]
                if leaf >= 0:
                    absorbed[leaf, c] += dep
                else:
                    absorbed_wood[c] += dep
            if a_r + a_t <= 0.0:
                continue
            mode = 0 if u[i, 0] * (a_r + a_t) < a_r else 1
            # u (a_r + a_t) rounds up to a_r when they are subnormal (a wood reflectance of 5e-324): never pick
            # an event of zero weight, whose weight factor would divide by zero
            if mode == 1 and a_t <= 0.0:
                mode = 0
            keep = a_r + a_t
        else:
            # analog absorption: the event is the Russian roulette
            x = u[i, 0] * total
            if x < a_r:
                mode = 0
            elif x < a_r + a_t:
                mode = 1
            else:
                mode = 2
            if mode == 2 and a_a <= 0.0:  # the same rounding at the top of the range
                mode = 0 if a_t <= 0.0 else 1
            elif mode == 1 and a_t <= 0.0:
                mode = 0
            if mode == 2:
                f = total / a_a
                for c in range(3):
                    dep = w[i, c] * absp[j, c] * f
                    if leaf >= 0:
                        absorbed[leaf, c] += dep
                    else:
                        absorbed_wood[c] += dep
                continue
            keep = total
        nx, ny, nz = normals[j, 0], normals[j, 1], normals[j, 2]
        # side the photon came from: against its direction
        side = 1.0 if nx * d[i, 0] + ny * d[i, 1] + nz * d[i, 2] <= 0.0 else -1.0
        if mode == 1:
            side = -side
        ax, ay, az = side * nx, side * ny, side * nz
        if mode == 0:
            f = keep / a_r
            for c in range(3):
                w_out[m, c] = w[i, c] * refl[j, c] * f
        else:
            f = keep / a_t
            for c in range(3):
                w_out[m, c] = w[i, c] * trans[j, c] * f
        # orthonormal basis about (ax, ay, az): Duff et al. 2017, JCGT 6(1), listing 3
        sg = 1.0 if az >= 0.0 else -1.0
        aa = -1.0 / (sg + az)
        bb = ax * ay * aa
        t1x, t1y, t1z = 1.0 + sg * ax * ax * aa, sg * bb, -sg * ax
        t2x, t2y, t2z = bb, sg + ay * ay * aa, -ay
        rr = math.sqrt(u[i, 1])
        phi = 2.0 * math.pi * u[i, 2]
        zz = math.sqrt(max(0.0, 1.0 - u[i, 1]))
        cx, cy = rr * math.cos(phi), rr * math.sin(phi)
        d_out[m, 0] = cx * t1x + cy * t2x + zz * ax
        d_out[m, 1] = cx * t1y + cy * t2y + zz * ay
        d_out[m, 2] = cx * t1z + cy * t2z + zz * az
        o_out[m, 0] = pts[i, 0] + offset * ax
        o_out[m, 1] = pts[i, 1] + offset * ay
        o_out[m, 2] = pts[i, 2] + offset * az
        m += 1
    return m


@dataclass
class _Tally:
    incidence: np.ndarray  # (4 L, 3): [leaf * 4 + category]
    absorbed: np.ndarray  # (L, 3)
    absorbed_wood: np.ndarray  # (3,)
    escaped: np.ndarray  # (3,)
    hits: np.ndarray  # (L,) int64
    truncated: int
    intercepted: np.ndarray  # (3,) surface sun source: power of the first hits drawn
    instances: np.ndarray  # (4 N, 3): [instance * 4 + category], placements only (N = 0 otherwise)

    @classmethod
    def zeros(cls, n_leaves: int, n_instances: int = 0) -> _Tally:
        return cls(
            np.zeros((4 * n_leaves, 3)), np.zeros((n_leaves, 3)), np.zeros(3), np.zeros(3),
            np.zeros(n_leaves, dtype=np.int64), 0, np.zeros(3), np.zeros((4 * n_instances, 3)),
        )

    def scaled(self, f: float) -> _Tally:
        """A copy with every power multiplied by f (counts unchanged)."""
        return _Tally(self.incidence * f, self.absorbed * f, self.absorbed_wood * f, self.escaped * f,
                      self.hits.copy(), self.truncated, self.intercepted * f, self.instances * f)

    def add(self, other: _Tally) -> None:
        self.incidence += other.incidence
        self.absorbed += other.absorbed
        self.absorbed_wood += other.absorbed_wood
        self.escaped += other.escaped
        self.hits += other.hits
        self.truncated += other.truncated
        self.intercepted += other.intercepted
        self.instances += other.instances


class _Tracer:
    """Everything a batch needs, shared read-only between threads."""

    def __init__(self, inputs: ReferenceInputs, max_events: int, ev_fraction: float, split: int = 1) -> None:
        self.ev_fraction = ev_fraction
        self.split = split
        self.periodic = inputs.period is not None
        self.placements = inputs.placements
        self.n_leaves = inputs.n_leaves
        self.n_instances = 0
        opt = inputs.optics
        # r + t = 1 in floating point leaves residues of ~1e-16: albedo 1 absorbs exactly nothing
        # (rows: 0 wood (ρ, 0), 1 leaf (r, t))
        self.r2 = np.stack([opt.wood_reflectance, opt.reflectance])
        self.t2 = np.stack([np.zeros(3), opt.transmittance])
        a2 = 1.0 - self.r2 - self.t2
        self.a2 = np.where(a2 > 1e-12, a2, 0.0)
        self.scene: InstancedRayScene | PeriodicRayScene | RayScene
        if self.placements is not None:
            pl = self.placements
            self.scene = InstancedRayScene(pl.triangles, pl.transforms, pl.prototype_of)
            self.n_instances = pl.n_instances
        elif self.periodic:
            self.scene = PeriodicRayScene(inputs.triangles, period=inputs.period, origin=inputs.cell_origin)
        else:
            self.scene = RayScene(inputs.triangles)
        self.offset = self.scene.offset_distance()
        if self.placements is None:
            assert not isinstance(self.scene, InstancedRayScene)  # built above from the triangles when there are no placements
            self.normals = self.scene.normals
            self.leaf = inputs.leaf_of_triangle
            # per-triangle r and t: leaves (r, t), wood (ρ, 0)
            kind = (self.leaf >= 0).astype(np.int64)
            self.r, self.t, self.a = self.r2[kind], self.t2[kind], self.a2[kind]
        self.max_events = max_events

    def first_hits(self, o, d):
        """(hits, hit points, truncated) for rays; ``hits`` is the triangle id (-1 for escapes) or, with
        placements, the (instance, prototype triangle) pair (-1, -1 for escapes)."""
        if isinstance(self.scene, PeriodicRayScene):  # self.periodic
            h = self.scene.intersect(o, d)
            return h.tri_id, h.points, h.truncated
        if isinstance(self.scene, InstancedRayScene):  # self.placements
            inst, tri, t = self.scene.intersect(o, d)
            pts = o + np.where(inst >= 0, t, 0.0)[:, None] * d
            return (inst, tri), pts, None
        tri, t = self.scene.intersect(o, d)
        pts = o + np.where(tri >= 0, t, 0.0)[:, None] * d
        return tri, pts, None

    def surfaces(self, hits):
        """What ``_process_hits`` reads of the surfaces hit: (ids, leaf of id, normals, r, t, a).

        Over copied triangles the ids are the triangles; with placements each hit gets its own id 0..k-1 and
        rows of its own (its result leaf, its world normal, its optics), so nothing grows with the instances.
        """
        if self.placements is None:
            return hits, self.leaf, self.normals, self.r, self.t, self.a
        inst, tri = hits
        pl = self.placements
        hit = inst >= 0
        ids = np.where(hit, np.arange(inst.size), -1)
        i, t = np.where(hit, inst, 0), np.where(hit, tri, 0)
        local = np.full(inst.size, -1, np.int64)
        for p, leaf_ids in enumerate(pl.leaf_of_triangle):
            sel = np.flatnonzero(hit & (pl.prototype_of[i] == p))
            local[sel] = leaf_ids[t[sel]]
        leaf = np.where(local >= 0, pl.leaf_offset[i] + local, -1)
        assert isinstance(self.scene, InstancedRayScene)  # built from the placements
        normals = self.scene.world_normals(i, t)
        kind = (local >= 0).astype(np.int64)
        return ids, leaf, normals, self.r2[kind], self.t2[kind], self.a2[kind]

    def tally_instances(self, hits, leaf, w, scattered, first_category, out) -> None:
        """Add each photon arriving at a leaf to its instance's tally (placements only)."""
        if self.placements is None:
            return
        inst = hits[0]
        on = np.flatnonzero(leaf >= 0)
        key = inst[on] * 4 + first_category + scattered[on].astype(np.int64)
        for c in range(3):
            out[:, c] += np.bincount(key, weights=w[on, c], minlength=out.shape[0])

    def run(self, source, rng: np.random.Generator, k: int, sky: bool) -> _Tally:
        tally = _Tally.zeros(self.n_leaves, self.n_instances)
        escaped = np.zeros(3)
        first_category = _SKY_DIRECT if sky else _SUN_DIRECT
        surface = isinstance(source, (_SurfaceSunSource, _PlacedSunSource))
        split = self.split if surface else 1
        o_out, d_out, w_out = (np.empty((k * split, 3)) for _ in range(3))
        if surface:
            tri0, pts0, d, w, weight = source.first_hits(rng, k)
            tally.intercepted += w.sum(axis=0)
            if split > 1:
                # splitting at the first hit: each first hit goes on as `split` photons of 1/split its power,
                # each with its own scattering event and direction (the shadow ray is paid once)
                rep = (lambda a: tuple(np.repeat(x, split) for x in a)) if isinstance(tri0, tuple) else \
                    (lambda a: np.repeat(a, split))
                tri0, pts0, d, w = rep(tri0), np.repeat(pts0, split, 0), np.repeat(d, split, 0), \
                    np.repeat(w / split, split, 0)
            o = pts0
            w_min = 3.0 * weight * self.ev_fraction / split
        else:
            o, d, w = source.emit(rng, k)
            w_min = float(w[0].sum()) * self.ev_fraction if k else 0.0
        scattered = np.zeros(o.shape[0], dtype=bool)
        for event in range(self.max_events + 1):
            n = o.shape[0]
            if n == 0:
                break
            if surface and event == 0:
                tri, pts, trunc = tri0, pts0, None
            else:
                tri, pts, trunc = self.first_hits(o, d)
            if trunc is not None and np.any(trunc):
                tally.truncated += int(trunc.sum())
                keep = ~trunc
                d, w, scattered, tri, pts = d[keep], w[keep], scattered[keep], tri[keep], pts[keep]
                n = tri.shape[0]
            u = rng.random((n, 3))
            ids, leaf, normals, refl, trans, absp = self.surfaces(tri)
            self.tally_instances(tri, leaf, w, scattered, first_category, tally.instances)
            m = _process_hits(
                ids, pts, d, w, scattered, leaf, normals, refl, trans, absp, u, self.offset,
                first_category, not sky, w_min, tally.incidence, tally.absorbed, tally.absorbed_wood, escaped,
                tally.hits, o_out, d_out, w_out,
            )
            o, d, w = o_out[:m].copy(), d_out[:m].copy(), w_out[:m].copy()
            scattered = np.ones(m, dtype=bool)
        else:
            tally.truncated += int(o.shape[0])
        tally.escaped += escaped
        return tally
