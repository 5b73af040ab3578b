"""Ray casting against triangle soups with Embree (through ``embreex``).

Used by the Monte Carlo reference (:mod:`foliage_tools.lighting.reference`)
and by any method that needs ray counts or distances through leaf geometry.

* :class:`RayScene` -- first hit of each ray in a set of triangles:
  ``intersect(origins, directions) -> (tri_id, t)``.
* :class:`PeriodicRayScene` -- the same for geometry repeated periodically in
  x and y (an infinite canopy layer made of one cell), for tests against
  plane-parallel solvers.

Precision
---------
Embree works in float32 and always starts rays at ``tnear = 0``. Two things
follow, and this module deals with the first:

* the distance Embree reports is rounded to float32 relative to the whole ray
  length. With ``refine=True`` (default) the distance of every hit is
  recomputed in float64 against the plane of the hit triangle,
  ``t = n·(v0 - o) / (n·d)``, so hit points lie on the (float64) triangle
  plane to rounding. This is skipped for grazing hits (``|n·d| < 1e-3 |d|``),
  where the plane intersection is ill-conditioned and Embree's value is kept.
* a ray started *on* a surface may hit that surface again at t ≈ 0. Callers
  that continue a path from a hit point must start the new ray slightly off
  the surface, on the side it leaves to: :meth:`RayScene.offset_distance`
  gives a safe offset for the scene's coordinate magnitude.

Pure numpy + embreex; no files, no printing.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

__all__ = ["MISS", "PeriodicHits", "PeriodicRayScene", "RayScene"]

#: ``tri_id`` of a ray that hits nothing (its ``t`` is ``inf``).
MISS = -1

#: Rays handed to Embree per call; also the unit of work split across threads.
DEFAULT_CHUNK = 1 << 16

#: Below this |n·d| / |d| a hit is "grazing" and its distance is not refined.
_GRAZING = 1e-3

#: Offset from a surface, relative to the scene's coordinate magnitude. float32
#: rounds coordinates to 6e-8 relative; vertices and ray origins are both
#: rounded, so an origin closer than ~2e-7 relative may land on the wrong side
#: of the plane it leaves. 4e-6 keeps a factor 20 of margin while staying far
#: below any leaf spacing.
_OFFSET_RELATIVE = 4e-6

#: Embree's "no hit" distance in embreex (``tfar`` is left at this value).
_EMBREE_FAR = np.float32(1e37)


def _as_triangles(triangles) -> np.ndarray:
    tri = np.asarray(triangles, dtype=np.float64)
    if tri.ndim != 3 or tri.shape[1:] != (3, 3):
        raise ValueError(f"triangles must have shape (T, 3, 3), got {tri.shape}")
    if not np.all(np.isfinite(tri)):
        raise ValueError("triangles contain NaN or infinite coordinates")
    return tri


def _as_rays(origins, directions) -> tuple[np.ndarray, np.ndarray]:
    o = np.asarray(origins, dtype=np.float64)
    d = np.asarray(directions, dtype=np.float64)
    if o.ndim != 2 or o.shape[1] != 3:
        raise ValueError(f"origins must have shape (N, 3), got {o.shape}")
    if d.shape != o.shape:
        raise ValueError(f"directions must have the shape of origins {o.shape}, got {d.shape}")
    if not (np.all(np.isfinite(o)) and np.all(np.isfinite(d))):
        raise ValueError("ray origins and directions must be finite")
    return o, d


def _for_spans(n: int, chunk: int, workers: int, fn) -> None:
    """Call ``fn(a, b)`` for consecutive spans of ``chunk`` rays out of ``n``, on ``workers`` threads
    (Embree releases the GIL; each span writes its own slice, so the results do not depend on the threads)."""
    spans = [(a, min(a + chunk, n)) for a in range(0, n, chunk)]
    if workers == 1 or len(spans) == 1:
        for a, b in spans:
            fn(a, b)
    else:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            list(pool.map(lambda span: fn(*span), spans))


class RayScene:
    """First-hit ray queries against a fixed set of triangles (Embree BVH).

    Parameters
    ----------
    triangles : (T, 3, 3) array_like of float
        Triangle vertices in world space (any units). Degenerate (zero-area)
        triangles are kept (ids stay aligned) but are never reported as hit by
        Embree; their :attr:`normals` are zero.

    Notes
    -----
    The BVH is built once; queries are thread-safe (Embree scenes are
    read-only after commit, and embreex releases the GIL while tracing), so
    several threads may call :meth:`intersect` on one scene at the same time.
    """

    def __init__(self, triangles) -> None:
        from embreex import rtcore_scene as rtcs
        from embreex.mesh_construction import TriangleMesh

        tri = np.array(_as_triangles(triangles), dtype=np.float64)
        tri.flags.writeable = False
        self.triangles: np.ndarray = tri
        """(T, 3, 3) float64 vertices (a private, read-only copy)."""
        cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        norm = np.linalg.norm(cross, axis=1)
        normals = np.divide(cross, norm[:, None], out=np.zeros_like(cross), where=norm[:, None] > 0)
        normals.flags.writeable = False
        self.normals: np.ndarray = normals
        """(T, 3) unit geometric normals, (v1 - v0) × (v2 - v0) normalised; zero for degenerate triangles."""
        self.areas: np.ndarray = 0.5 * norm
        """(T,) triangle areas."""
        if tri.shape[0]:
            lo = tri.reshape(-1, 3).min(axis=0)
            hi = tri.reshape(-1, 3).max(axis=0)
        else:
            lo = hi = np.zeros(3)
        self.bounds: np.ndarray = np.stack([lo, hi])
        """(2, 3) axis-aligned bounds (min, max); zeros for an empty scene."""
        self._scene = None
        if tri.shape[0]:
            self._scene = rtcs.EmbreeScene()
            TriangleMesh(self._scene, np.ascontiguousarray(tri, dtype=np.float32))
            # Commit now (embreex commits on the first query, which is not
            # thread-safe): a zero-length query forces the BVH build.
            empty = np.zeros((1, 3), dtype=np.float32)
            self._scene.run(empty, np.array([[0.0, 0.0, 1.0]], dtype=np.float32), dists=np.zeros(1, np.float32))

    @property
    def n_triangles(self) -> int:
        return int(self.triangles.shape[0])

    def offset_distance(self) -> float:
        """Distance by which to move a ray origin off a surface it starts on.

        Relative to the largest absolute coordinate and the bounds' diagonal
        (float32 rounding of vertices and origins scales with the coordinate
        magnitude, see the module docstring).
        """
        scale = max(float(np.max(np.abs(self.bounds))), float(np.linalg.norm(self.bounds[1] - self.bounds[0])), 1e-30)
        return _OFFSET_RELATIVE * scale

    def intersect(
        self,
        origins,
        directions,
        *,
        tfar=None,
        refine: bool = True,
        workers: int = 1,
        chunk: int = DEFAULT_CHUNK,
    ) -> tuple[np.ndarray, np.ndarray]:
        """First hit of each ray.

        Parameters
        ----------
        origins, directions : (N, 3) array_like of float
            Ray origins and directions (directions need not be unit; ``t`` is
            in units of ``|direction|``). Rays start at t = 0.
        tfar : float or (N,) array_like, optional
            Largest distance searched (exclusive of farther hits); default inf.
        refine : bool
            Recompute hit distances in float64 against the hit triangle's plane
            (see the module docstring).
        workers : int
            Threads used to split the rays (results are identical for any value).
        chunk : int
            Rays per Embree call.

        Returns
        -------
        tri_id : (N,) int64
            Index of the first triangle hit, ``MISS`` (-1) for no hit.
        t : (N,) float64
            Distance to the hit along the ray, ``inf`` for no hit.
        """
        o, d = _as_rays(origins, directions)
        n = o.shape[0]
        if tfar is None:
            far = np.full(n, np.inf)
        else:
            far = np.broadcast_to(np.asarray(tfar, dtype=np.float64), (n,))
            if np.any(np.isnan(far)):
                raise ValueError("tfar must not be NaN")
        if chunk < 1:
            raise ValueError(f"chunk must be >= 1 ray, got {chunk}")
        if workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        tri_id = np.full(n, MISS, dtype=np.int64)
        t = np.full(n, np.inf)
        if n == 0 or self._scene is None:
            return tri_id, t
        _for_spans(n, chunk, workers, lambda a, b: self._run(o[a:b], d[a:b], far[a:b], tri_id[a:b], t[a:b], refine))
        return tri_id, t

    def occluded(self, origins, directions, *, workers: int = 1, chunk: int = DEFAULT_CHUNK) -> np.ndarray:
        """Whether each ray hits anything (an Embree occlusion query: any hit, not the first).

        Parameters
        ----------
        origins, directions : (N, 3) array_like of float
            Ray origins and directions; rays start at t = 0 and run to infinity.
        workers : int
            Threads used to split the rays (results are identical for any value).
        chunk : int
            Rays per Embree call.

        Returns
        -------
        numpy.ndarray (N,) bool
        """
        o, d = _as_rays(origins, directions)
        n = o.shape[0]
        out = np.zeros(n, dtype=bool)
        if n == 0 or self._scene is None:
            return out
        if chunk < 1 or workers < 1:
            raise ValueError(f"chunk and workers must be >= 1, got {chunk} and {workers}")

        scene = self._scene  # not None (checked above), for the closure

        def run(a: int, b: int) -> None:
            res = scene.run(
                np.ascontiguousarray(o[a:b], dtype=np.float32),
                np.ascontiguousarray(d[a:b], dtype=np.float32),
                query="OCCLUDED",
            )
            out[a:b] = np.asarray(res) >= 0

        _for_spans(n, chunk, workers, run)
        return out

    def _run(self, o, d, far, tri_out, t_out, refine) -> None:
        """Trace one chunk into the given output slices."""
        assert self._scene is not None  # intersect calls this only for a scene with triangles
        dists = np.minimum(far, float(_EMBREE_FAR)).astype(np.float32)
        res = self._scene.run(
            np.ascontiguousarray(o, dtype=np.float32),
            np.ascontiguousarray(d, dtype=np.float32),
            dists=dists,
            output=1,
        )
        prim = res["primID"].astype(np.int64)
        hit = prim >= 0
        tri_out[hit] = prim[hit]
        t_hit = res["tfar"][hit].astype(np.float64)
        if refine and np.any(hit):
            idx = prim[hit]
            n = self.normals[idx]
            dh = d[hit]
            ndotd = np.einsum("ij,ij->i", n, dh)
            good = np.abs(ndotd) >= _GRAZING * np.linalg.norm(dh, axis=1)
            num = np.einsum("ij,ij->i", n, self.triangles[idx, 0] - o[hit])
            t_plane = np.divide(num, ndotd, out=t_hit.copy(), where=good)
            t_hit = np.where(good, np.maximum(t_plane, 0.0), t_hit)
        t_out[hit] = t_hit


@dataclass(frozen=True)
class PeriodicHits:
    """First hits in a periodic scene (see :meth:`PeriodicRayScene.intersect`)."""

    tri_id: np.ndarray
    """(N,) int64 index into the cell's triangles, -1 for no hit."""
    t: np.ndarray
    """(N,) float64 distance travelled (over all cells crossed), inf for no hit."""
    points: np.ndarray
    """(N, 3) float64 hit points mapped into the base cell; NaN for no hit."""
    truncated: np.ndarray
    """(N,) bool: rays abandoned after ``max_segments`` cell crossings (reported as no hit)."""


class PeriodicRayScene:
    """Triangles of one cell, repeated with periods ``px``, ``py`` along x and y.

    An infinite horizontal layer (z bounded by the triangles) made of copies of
    one cell ``[x0, x0 + px) × [y0, y0 + py)``. A ray is followed in the base
    cell; when it leaves through a side it re-enters through the opposite side
    (which is the same as entering the neighbouring copy), until it hits a
    triangle or leaves the layer through its top or bottom.

    Parameters
    ----------
    triangles : (T, 3, 3) array_like of float
        Geometry of one cell. Triangles may straddle the cell's sides, but
        every vertex must lie within one period of the cell,
        ``x0 - px < x < x0 + 2 px`` (and likewise in y): the scene traces
        against the 3 × 3 block of copies around the base cell.
    period : (float, float)
        Periods px, py (> 0) in x and y.
    origin : (float, float)
        Lower corner (x0, y0) of the base cell.
    """

    def __init__(self, triangles, *, period, origin=(0.0, 0.0)) -> None:
        tri = _as_triangles(triangles)
        p = np.asarray(period, dtype=np.float64).reshape(-1)
        c = np.asarray(origin, dtype=np.float64).reshape(-1)
        if p.shape != (2,) or not np.all(np.isfinite(p)) or np.any(p <= 0):
            raise ValueError(f"period must be two positive numbers (px, py), got {period!r}")
        if c.shape != (2,) or not np.all(np.isfinite(c)):
            raise ValueError(f"origin must be two numbers (x0, y0), got {origin!r}")
        if tri.shape[0]:
            xy = tri[..., :2].reshape(-1, 2)
            if np.any(xy <= c - p) or np.any(xy >= c + 2 * p):
                raise ValueError(
                    "periodic scene: every vertex must lie within one period of the cell "
                    f"[{c[0]}, {c[0] + p[0]}) x [{c[1]}, {c[1] + p[1]}) (the 3 x 3 block of copies is traced)"
                )
        self.period = p
        self.origin = c
        self.n_triangles = int(tri.shape[0])
        offsets = np.array([(i * p[0], j * p[1], 0.0) for i in (-1, 0, 1) for j in (-1, 0, 1)])
        tiled = (tri[None, :, :, :] + offsets[:, None, None, :]).reshape(-1, 3, 3)
        self._tiles = RayScene(tiled)
        self.normals = self._tiles.normals[: self.n_triangles] if self.n_triangles else np.zeros((0, 3))
        if self.n_triangles:
            self.bounds = np.stack([tri.reshape(-1, 3).min(axis=0), tri.reshape(-1, 3).max(axis=0)])
        else:
            self.bounds = np.zeros((2, 3))
        # The layer's vertical extent, with a margin so rays started on its
        # top or bottom faces are inside.
        margin = 1e-6 * max(float(np.ptp(self.bounds[:, 2])), float(p.max()))
        self.z_range = (float(self.bounds[0, 2]) - margin, float(self.bounds[1, 2]) + margin)

    def offset_distance(self) -> float:
        """See :meth:`RayScene.offset_distance` (taken over the 3 x 3 block)."""
        return self._tiles.offset_distance()

    def occluded(self, origins, directions, *, workers: int = 1) -> np.ndarray:
        """(N,) bool: whether each ray hits a triangle of the infinite layer (see :meth:`intersect`)."""
        hits = self.intersect(origins, directions)
        if np.any(hits.truncated):
            raise RuntimeError(f"{int(hits.truncated.sum())} occlusion ray(s) crossed too many cells of the periodic layer")
        return hits.tri_id >= 0

    def wrap(self, points) -> np.ndarray:
        """Map points into the base cell (x and y modulo the periods)."""
        q = np.array(points, dtype=np.float64)
        q[:, :2] = self.origin + np.mod(q[:, :2] - self.origin, self.period)
        return q

    def intersect(self, origins, directions, *, max_segments: int = 100_000) -> PeriodicHits:
        """First hit of each ray in the infinite periodic layer.

        Parameters
        ----------
        origins, directions : (N, 3) array_like of float
            Origins anywhere (mapped into the base cell first); directions
            must be unit vectors (``t`` is a length).
        max_segments : int
            Cell crossings after which a ray is given up (flagged in
            ``truncated``); only near-horizontal rays in a sparse layer get
            there.

        Returns
        -------
        PeriodicHits
        """
        o, d = _as_rays(origins, directions)
        n = o.shape[0]
        tri_id = np.full(n, MISS, dtype=np.int64)
        t_total = np.full(n, np.inf)
        points = np.full((n, 3), np.nan)
        truncated = np.zeros(n, dtype=bool)
        if n == 0:
            return PeriodicHits(tri_id, t_total, points, truncated)
        cur = self.wrap(o)
        travelled = np.zeros(n)
        active = np.arange(n)
        lo = np.array([self.origin[0], self.origin[1], self.z_range[0]])
        hi = np.array([self.origin[0] + self.period[0], self.origin[1] + self.period[1], self.z_range[1]])
        with np.errstate(divide="ignore", invalid="ignore"):
            for _ in range(max_segments):
                if active.size == 0:
                    break
                oa = cur[active]
                da = d[active]
                # distance to leave the cell box along each axis
                bound = np.where(da > 0, hi, lo)
                t_axis = np.where(da != 0, (bound - oa) / da, np.inf)
                t_axis = np.maximum(t_axis, 0.0)
                axis = np.argmin(t_axis, axis=1)
                t_exit = t_axis[np.arange(active.size), axis]
                if self.n_triangles:
                    tri, t = self._tiles.intersect(oa, da, tfar=t_exit)
                else:
                    tri, t = np.full(active.size, MISS), np.full(active.size, np.inf)
                hit = tri >= 0
                ids = active[hit]
                tri_id[ids] = tri[hit] % self.n_triangles if self.n_triangles else MISS
                t_total[ids] = travelled[ids] + t[hit]
                points[ids] = oa[hit] + t[hit, None] * da[hit]
                # rays leaving through the top or bottom escape the layer
                through_side = ~hit & (axis < 2)
                moving = active[through_side]
                if moving.size:
                    ax = axis[through_side]
                    te = t_exit[through_side]
                    q = oa[through_side] + te[:, None] * da[through_side]
                    rows = np.arange(moving.size)
                    # re-enter exactly on the opposite side of the crossed
                    # axis (set after wrapping: hi would wrap back onto lo);
                    # the other side axis is wrapped in case of a corner exit.
                    entry = np.where(da[through_side][rows, ax] > 0, lo[ax], hi[ax])
                    q = self.wrap(q)
                    q[rows, ax] = entry
                    cur[moving] = q
                    travelled[moving] += te
                active = moving
        if active.size:
            truncated[active] = True
        points = np.where(tri_id[:, None] >= 0, self.wrap(np.nan_to_num(points)), np.nan)
        return PeriodicHits(tri_id, t_total, points, truncated)


def unit_rows(d, name: str) -> np.ndarray:
    """(N, 3) unit vectors from (N, 3) or (3,) input; ValueError naming ``name`` if not finite or zero."""
    a = np.asarray(d, dtype=np.float64)
    if a.ndim == 1:
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] != 3 or a.shape[0] < 1 or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite with shape (N, 3) or (3,), got {np.shape(d)}")
    n = np.linalg.norm(a, axis=1)
    if np.any(n == 0.0):
        raise ValueError(f"{name} must be non-zero vectors")
    return a / n[:, None]


def count_crossings(
    scene: RayScene,
    origins,
    directions,
    *,
    skip_ids=None,
    id_of_triangle=None,
    max_hits: int = 100_000,
    workers: int = 1,
) -> np.ndarray:
    """Triangles crossed by the ray from every origin along every direction, to infinity (shinya2013 eq. (29) counts n±).

    Parameters
    ----------
    scene : RayScene
    origins : (P, 3) array_like
    directions : (D, 3) array_like
        Normalised here.
    skip_ids : (P,) int, optional
        With ``id_of_triangle`` (T,): hits on triangles whose id equals the
        origin's ``skip_ids`` are not counted (the leaf the ray starts on).
    max_hits : int
        Safety bound on crossings per ray; a ray still hitting after that many
        raises ``RuntimeError`` (never a silent truncation).
    workers : int
        Threads for Embree.

    Returns
    -------
    numpy.ndarray (P, D) int64
    """
    o = np.asarray(origins, dtype=np.float64)
    if o.ndim != 2 or o.shape[1] != 3 or not np.all(np.isfinite(o)):
        raise ValueError(f"origins must be finite with shape (P, 3), got {np.shape(origins)}")
    dirs = unit_rows(directions, "directions")
    p, nd = o.shape[0], dirs.shape[0]
    skip = None
    if (skip_ids is None) != (id_of_triangle is None):
        raise ValueError("skip_ids and id_of_triangle go together")
    if skip_ids is not None:
        skip = np.asarray(skip_ids, dtype=np.int64).reshape(-1)
        tri_ids = np.asarray(id_of_triangle, dtype=np.int64).reshape(-1)
        if skip.shape != (p,) or tri_ids.shape != (scene.n_triangles,):
            raise ValueError(f"skip_ids must be ({p},) and id_of_triangle ({scene.n_triangles},)")
        skip = np.repeat(skip, nd)
    ro = np.repeat(o, nd, axis=0)
    rd = np.tile(dirs, (p, 1))
    counts = np.zeros(p * nd, dtype=np.int64)
    eps = scene.offset_distance()
    ro = ro + eps * rd
    live = np.arange(p * nd)
    for _ in range(max_hits):
        if live.size == 0:
            break
        tri, t = scene.intersect(ro[live], rd[live], workers=workers)
        hit = tri >= 0
        hl = live[hit]
        if skip is not None:
            own = tri_ids[tri[hit]] == skip[hl]
            counts[hl[~own]] += 1
        else:
            counts[hl] += 1
        ro[hl] += (t[hit, None] + eps) * rd[hl]
        live = hl
    else:
        if live.size:
            raise RuntimeError(f"{live.size} ray(s) crossed more than max_hits = {max_hits} triangles")
    return counts.reshape(p, nd)
