"""Ray queries through instanced geometry without copying it: a two-level scene.

embreex exposes Embree's triangle meshes but not its instances, so a forest
of N placements of a few prototypes would otherwise be one ray scene of every
instance's triangles (~760 B per triangle: 10 000 trees of 15 000 triangles
need ~110 GB). :class:`InstancedRayScene` keeps one Embree scene per
prototype, in the prototype's own frame, and a top level of its own over the
instances' world bounding boxes:

* **Top level**: a uniform grid over the instances' world boxes (cells about
  the median instance's size, so a box overlaps a few cells), each cell
  listing the instances whose box overlaps it. A ray walks the cells it
  crosses (Amanatides & Woo 1987, "A fast voxel traversal algorithm for ray
  tracing", Eurographics) and collects every instance box it enters, with
  the distance at which it enters it, sorted per ray.
* **Bottom level**: a candidate (ray, instance) is traced in the instance's
  prototype scene with the ray mapped into the prototype frame,
  o' = A⁻¹(o − b), d' = A⁻¹d (the instance maps x to A x + b). The direction
  is not renormalised, so the distance t along the ray is the same in both
  frames, and the nearest hit over the candidates is the world's nearest hit.
* **Waves**: candidates are tried nearest box first, a growing number per ray
  per round (1, 2, 4, ...), and a ray is done once its next box starts beyond
  its nearest hit so far; an occlusion ray is done at its first hit. So a ray
  pays for the boxes in front of its hit, not for every box it crosses.

Hits are reported as (instance, triangle of the prototype); world normals are
the prototype normals mapped by A⁻ᵀ. Results equal a flat :class:`RayScene`
of the copied triangles up to float32 rounding in a different frame (a
test compares them hit by hit).

Pure numpy + numba + embreex; no files, no printing.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numba import njit

from foliage_tools.geometry.rays import MISS, RayScene, _OFFSET_RELATIVE, _as_rays

__all__ = ["InstancedRayScene", "cofactors"]

#: Most cells of the top-level grid (a cell costs 8 B of offsets).
_MAX_CELLS = 1 << 22


def cofactors(linear: np.ndarray) -> np.ndarray:
    """(N, 3, 3) cofactor matrices det(A) A⁻ᵀ of invertible (N, 3, 3) maps A: a placed triangle's area vector is
    cof(A) a (a: its area vector before the map), so its area is |cof(A) a| and its projection on s is a·(cof(A)ᵀ s)."""
    linear = np.asarray(linear, dtype=np.float64)
    if len(linear) == 0:
        return np.zeros((0, 3, 3))
    return np.linalg.det(linear)[:, None, None] * np.transpose(np.linalg.inv(linear), (0, 2, 1))


class InstancedRayScene:
    """First-hit and occlusion queries through N placements of a few prototypes.

    Parameters
    ----------
    prototypes : sequence of (T_p, 3, 3) array_like
        Each prototype's triangles in its own frame.
    transforms : (N, 4, 4) array_like
        World-from-prototype matrices, column-vector convention
        (``p_world = M @ [x, y, z, 1]``); the 3×3 part must be invertible.
    prototype_of : (N,) array_like of int
        The prototype each instance places.
    """

    def __init__(self, prototypes: Sequence, transforms, prototype_of) -> None:
        self.scenes = [RayScene(p) for p in prototypes]
        m = np.asarray(transforms, dtype=np.float64)
        if m.ndim != 3 or m.shape[1:] != (4, 4):
            raise ValueError(f"transforms must have shape (N, 4, 4), got {m.shape}")
        if not np.all(np.isfinite(m)):
            raise ValueError("transforms contain NaN or infinite entries")
        proto = np.asarray(prototype_of, dtype=np.int64).reshape(-1)
        if proto.shape != (m.shape[0],):
            raise ValueError(f"prototype_of must have one entry per transform ({m.shape[0]}), got {proto.shape}")
        if proto.size and (proto.min() < 0 or proto.max() >= len(self.scenes)):
            raise ValueError(f"prototype_of must index the {len(self.scenes)} prototypes, got {proto.min()}..{proto.max()}")
        self.linear = np.ascontiguousarray(m[:, :3, :3])
        """(N, 3, 3) the instances' linear parts A."""
        self.translation = np.ascontiguousarray(m[:, :3, 3])
        """(N, 3) the instances' translations b."""
        det = np.linalg.det(self.linear) if len(m) else np.zeros(0)
        scale = np.abs(self.linear).reshape(len(m), -1).max(axis=1) if len(m) else np.zeros(0)
        bad = np.flatnonzero(~(np.abs(det) > 1e-12 * scale**3))
        if bad.size:
            raise ValueError(f"instance {int(bad[0])}'s transform is singular (det {det[bad[0]]:.3g}): it flattens its tree")
        self.inverse = np.ascontiguousarray(np.linalg.inv(self.linear)) if len(m) else np.zeros((0, 3, 3))
        """(N, 3, 3) A⁻¹."""
        self.prototype_of = proto
        lo, hi = _instance_boxes(self.scenes, self.linear, self.translation, proto)
        self.instance_bounds = np.stack([lo, hi], axis=1)
        """(N, 2, 3) world bounding box of each instance (min, max corner)."""
        live = np.array([self.scenes[p].n_triangles > 0 for p in proto], dtype=bool)
        self._grid = _Grid(lo[live], hi[live], np.flatnonzero(live))
        if live.any():
            self.bounds = np.stack([lo[live].min(axis=0), hi[live].max(axis=0)])
        else:
            self.bounds = np.zeros((2, 3))
        """(2, 3) world bounds of all instances."""

    @property
    def n_instances(self) -> int:
        return int(self.prototype_of.shape[0])

    def offset_distance(self) -> float:
        """Distance by which to move a ray origin off a surface it starts on (world scale, as :class:`RayScene`)."""
        scale = max(float(np.max(np.abs(self.bounds))), float(np.linalg.norm(self.bounds[1] - self.bounds[0])), 1e-30)
        return _OFFSET_RELATIVE * scale

    def world_normals(self, instance: np.ndarray, triangle: np.ndarray) -> np.ndarray:
        """(K, 3) unit world normals of prototype triangles ``triangle`` placed by ``instance`` (A⁻ᵀ n, normalised)."""
        instance = np.asarray(instance, dtype=np.int64)
        triangle = np.asarray(triangle, dtype=np.int64)
        out = np.zeros((instance.size, 3))
        for p, scene in enumerate(self.scenes):
            sel = np.flatnonzero(self.prototype_of[instance] == p)
            if sel.size:
                n = np.einsum("kji,kj->ki", self.inverse[instance[sel]], scene.normals[triangle[sel]])
                norm = np.linalg.norm(n, axis=1)
                out[sel] = np.divide(n, norm[:, None], out=np.zeros_like(n), where=norm[:, None] > 0)
        return out

    def _local(self, inst: np.ndarray, rays: np.ndarray, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rays ``rays`` mapped into the frames of instances ``inst``: A⁻¹(o − b), A⁻¹d."""
        return _to_local(inst, rays, o, d, self.inverse, self.translation)

    def intersect(self, origins, directions, *, tfar=None, workers: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Nearest hit of each ray.

        Parameters
        ----------
        origins, directions : (R, 3) array_like of float
            World rays (directions need not be unit; ``t`` is in units of ``|direction|``), from t = 0.
        tfar : float or (R,) array_like, optional
            Largest distance searched; default inf.
        workers : int
            Threads for the prototype traces (results do not depend on it).

        Returns
        -------
        instance, triangle : (R,) int64
            The instance hit and the triangle of its prototype; ``MISS`` (-1) for no hit.
        t : (R,) float64
            Distance to the hit, ``inf`` for no hit.
        """
        o, d = _as_rays(origins, directions)
        n = o.shape[0]
        best = np.full(n, np.inf) if tfar is None else np.array(np.broadcast_to(np.asarray(tfar, np.float64), (n,)))
        inst_hit = np.full(n, MISS, dtype=np.int64)
        tri_hit = np.full(n, MISS, dtype=np.int64)
        start, cand, t_enter = self._grid.candidates(o, d, best)
        cursor = start[:-1].copy()
        end = start[1:]
        width = 1
        while True:
            idx = np.flatnonzero(cursor < end)
            idx = idx[t_enter[cursor[idx]] < best[idx]]
            if idx.size == 0:
                break
            rays, pos = _next_candidates(idx, cursor, end, width)
            keep = t_enter[pos] < best[rays]
            rays, inst = rays[keep], cand[pos[keep]]
            for p, scene in enumerate(self.scenes):
                sel = np.flatnonzero(self.prototype_of[inst] == p)
                if sel.size == 0:
                    continue
                r, i = rays[sel], inst[sel]
                lo, ld = self._local(i, r, o, d)
                tri, t = scene.intersect(lo, ld, tfar=best[r], workers=workers)
                hit = np.flatnonzero((tri >= 0) & (t < best[r]))
                if hit.size == 0:
                    continue
                # several candidates of one ray may hit: write farthest first, so the nearest is written last
                hit = hit[np.argsort(-t[hit], kind="stable")]
                best[r[hit]] = t[hit]
                inst_hit[r[hit]] = i[hit]
                tri_hit[r[hit]] = tri[hit]
            width *= 2
        t_out = np.where(inst_hit >= 0, best, np.inf)
        return inst_hit, tri_hit, t_out

    def occluded(self, origins, directions, *, workers: int = 1) -> np.ndarray:
        """Whether each ray (from t = 0 to infinity) hits anything."""
        o, d = _as_rays(origins, directions)
        n = o.shape[0]
        out = np.zeros(n, dtype=bool)
        start, cand, _ = self._grid.candidates(o, d, np.full(n, np.inf))
        cursor = start[:-1].copy()
        end = start[1:]
        width = 1
        while True:
            idx = np.flatnonzero((cursor < end) & ~out)
            if idx.size == 0:
                break
            rays, pos = _next_candidates(idx, cursor, end, width)
            inst = cand[pos]
            for p, scene in enumerate(self.scenes):
                sel = np.flatnonzero(self.prototype_of[inst] == p)
                if sel.size == 0:
                    continue
                lo, ld = self._local(inst[sel], rays[sel], o, d)
                out[rays[sel][scene.occluded(lo, ld, workers=workers)]] = True
            width *= 2
        return out


def _next_candidates(idx: np.ndarray, cursor: np.ndarray, end: np.ndarray, width: int) -> tuple[np.ndarray, np.ndarray]:
    """The next ``width`` candidates (at most) of each ray in ``idx``: (ray, position in the CSR) pairs; advances
    the rays' cursors past them."""
    take = np.minimum(end[idx] - cursor[idx], width)
    rays = np.repeat(idx, take)
    pos = np.repeat(cursor[idx] - np.cumsum(take) + take, take) + np.arange(int(take.sum()))
    cursor[idx] += take
    return rays, pos


def _instance_boxes(scenes, linear, translation, proto) -> tuple[np.ndarray, np.ndarray]:
    """World boxes of the instances: each prototype box's 8 corners placed and bounded."""
    n = len(proto)
    lo = np.zeros((n, 3))
    hi = np.zeros((n, 3))
    for p, scene in enumerate(scenes):
        sel = np.flatnonzero(proto == p)
        if sel.size == 0:
            continue
        b = scene.bounds
        corners = np.array([[b[i, 0], b[j, 1], b[k, 2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
        w = np.einsum("nij,cj->nci", linear[sel], corners) + translation[sel, None, :]
        lo[sel] = w.min(axis=1)
        hi[sel] = w.max(axis=1)
    # a box grown by a relative hair, so float rounding of the placed triangles never falls outside it
    if n:
        pad = 1e-6 * np.maximum(np.abs(np.concatenate([lo, hi], axis=1)).max(axis=1), (hi - lo).max(axis=1))
        lo -= pad[:, None]
        hi += pad[:, None]
    return lo, hi


class _Grid:
    """The top level: a uniform grid of cells listing the instance boxes that overlap them."""

    def __init__(self, lo: np.ndarray, hi: np.ndarray, ids: np.ndarray) -> None:
        self.box_lo, self.box_hi, self.ids = lo, hi, ids.astype(np.int64)
        if len(ids) == 0:
            self.origin = np.zeros(3)
            self.cell = 1.0
            self.dims = np.ones(3, np.int64)
            self.start = np.zeros(2, np.int64)
            self.items = np.zeros(0, np.int64)
            return
        self.origin = lo.min(axis=0)
        extent = np.maximum(hi.max(axis=0) - self.origin, 1e-30)
        size = float(np.median((hi - lo).max(axis=1)))
        cell = max(size, float(extent.max()) * 1e-6)
        while np.prod(np.maximum(np.ceil(extent / cell), 1)) > _MAX_CELLS:
            cell *= 1.25
        self.cell = cell
        self.dims = np.maximum(np.ceil(extent / cell), 1).astype(np.int64)
        self.start, self.items = _bin_boxes(lo, hi, self.origin, cell, self.dims)

    def candidates(self, o: np.ndarray, d: np.ndarray, tfar: np.ndarray):
        """Per ray the instance boxes it enters before ``tfar``: CSR (start, instance, entry distance), nearest first."""
        n = o.shape[0]
        if len(self.ids) == 0 or n == 0:
            return np.zeros(n + 1, np.int64), np.zeros(0, np.int64), np.zeros(0)
        args = (o, d, tfar, self.origin, self.cell, self.dims, self.start, self.items, self.box_lo, self.box_hi)
        counts = np.zeros(n, np.int64)
        _walk(*args, counts, np.zeros(0, np.int64), np.zeros(0), np.zeros(0, np.int64), True)
        start = np.zeros(n + 1, np.int64)
        np.cumsum(counts, out=start[1:])
        slot = np.zeros(int(start[-1]), np.int64)
        t_enter = np.zeros(int(start[-1]))
        _walk(*args, counts, slot, t_enter, start, False)
        return start, self.ids[slot], t_enter


@njit(cache=True, nogil=True)
def _to_local(inst, rays, o, d, inverse, translation):
    k = inst.shape[0]
    lo = np.empty((k, 3))
    ld = np.empty((k, 3))
    for q in range(k):
        n = inst[q]
        r = rays[q]
        px = o[r, 0] - translation[n, 0]
        py = o[r, 1] - translation[n, 1]
        pz = o[r, 2] - translation[n, 2]
        for a in range(3):
            lo[q, a] = inverse[n, a, 0] * px + inverse[n, a, 1] * py + inverse[n, a, 2] * pz
            ld[q, a] = inverse[n, a, 0] * d[r, 0] + inverse[n, a, 1] * d[r, 1] + inverse[n, a, 2] * d[r, 2]
    return lo, ld


@njit(cache=True)
def _bin_boxes(lo, hi, origin, cell, dims):
    """CSR of the boxes overlapping each cell (cells in x-fastest order)."""
    n = lo.shape[0]
    ncell = dims[0] * dims[1] * dims[2]
    count = np.zeros(ncell + 1, np.int64)
    for pass_ in range(2):
        if pass_ == 1:
            for c in range(ncell):
                count[c + 1] += count[c]
            fill = count[:-1].copy()
            items = np.empty(count[ncell], np.int64)
        for k in range(n):
            a = np.empty(3, np.int64)
            b = np.empty(3, np.int64)
            for ax in range(3):
                a[ax] = min(max(int((lo[k, ax] - origin[ax]) / cell), 0), dims[ax] - 1)
                b[ax] = min(max(int((hi[k, ax] - origin[ax]) / cell), 0), dims[ax] - 1)
            for z in range(a[2], b[2] + 1):
                for y in range(a[1], b[1] + 1):
                    for x in range(a[0], b[0] + 1):
                        c = x + dims[0] * (y + dims[1] * z)
                        if pass_ == 0:
                            count[c + 1] += 1
                        else:
                            items[fill[c]] = k
                            fill[c] += 1
    return count, items


@njit(cache=True, nogil=True)
def _slab(o, d, lo, hi, k):
    """Entry and exit distances of ray (o, d) through box k (t0 > t1: no overlap)."""
    t0 = -np.inf
    t1 = np.inf
    for ax in range(3):
        if d[ax] != 0.0:
            inv = 1.0 / d[ax]
            a = (lo[k, ax] - o[ax]) * inv
            b = (hi[k, ax] - o[ax]) * inv
            if a > b:
                a, b = b, a
            t0 = max(t0, a)
            t1 = min(t1, b)
        elif o[ax] < lo[k, ax] or o[ax] > hi[k, ax]:
            return 1.0, -1.0
    return t0, t1


@njit(cache=True, nogil=True)
def _walk(o, d, tfar, origin, cell, dims, start, items, box_lo, box_hi, counts, slot, t_enter, out_start, count_only):
    """Walk each ray through the grid's cells (Amanatides & Woo 1987) and list the boxes it enters before tfar.

    ``count_only``: write the number per ray into ``counts``; else write (box, entry distance) from
    ``out_start[ray]`` on, sorted by entry distance.
    """
    n_box = box_lo.shape[0]
    seen = np.full(n_box, -1, np.int64)  # mailbox: the last ray that tested each box
    grid_lo = np.empty((1, 3))
    grid_hi = np.empty((1, 3))
    for ax in range(3):
        grid_lo[0, ax] = origin[ax]
        grid_hi[0, ax] = origin[ax] + dims[ax] * cell
    for r in range(o.shape[0]):
        ro = o[r]
        rd = d[r]
        g0, g1 = _slab(ro, rd, grid_lo, grid_hi, 0)
        g0 = max(g0, 0.0)
        g1 = min(g1, tfar[r])
        m = 0
        if g0 <= g1:
            t = g0
            idx = np.empty(3, np.int64)
            step = np.empty(3, np.int64)
            t_next = np.empty(3)
            t_delta = np.empty(3)
            for ax in range(3):
                p = ro[ax] + t * rd[ax]
                idx[ax] = min(max(int(np.floor((p - origin[ax]) / cell)), 0), dims[ax] - 1)
                if rd[ax] > 0.0:
                    step[ax] = 1
                    t_next[ax] = (origin[ax] + (idx[ax] + 1) * cell - ro[ax]) / rd[ax]
                    t_delta[ax] = cell / rd[ax]
                elif rd[ax] < 0.0:
                    step[ax] = -1
                    t_next[ax] = (origin[ax] + idx[ax] * cell - ro[ax]) / rd[ax]
                    t_delta[ax] = -cell / rd[ax]
                else:
                    step[ax] = 0
                    t_next[ax] = np.inf
                    t_delta[ax] = np.inf
            while True:
                c = idx[0] + dims[0] * (idx[1] + dims[1] * idx[2])
                for q in range(start[c], start[c + 1]):
                    k = items[q]
                    if seen[k] == r:
                        continue
                    seen[k] = r
                    b0, b1 = _slab(ro, rd, box_lo, box_hi, k)
                    b0 = max(b0, 0.0)
                    if b0 <= b1 and b0 < tfar[r]:
                        if not count_only:
                            # insertion into this ray's list, kept sorted by entry distance
                            base = out_start[r]
                            j = m
                            while j > 0 and t_enter[base + j - 1] > b0:
                                t_enter[base + j] = t_enter[base + j - 1]
                                slot[base + j] = slot[base + j - 1]
                                j -= 1
                            t_enter[base + j] = b0
                            slot[base + j] = k
                        m += 1
                ax = 0
                if t_next[1] < t_next[ax]:
                    ax = 1
                if t_next[2] < t_next[ax]:
                    ax = 2
                if t_next[ax] > g1:
                    break
                idx[ax] += step[ax]
                if idx[ax] < 0 or idx[ax] >= dims[ax]:
                    break
                t_next[ax] += t_delta[ax]
        if count_only:
            counts[r] = m
