"""Embree ray queries (foliage_tools.geometry.rays) against brute-force and closed-form answers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from foliage_tools.geometry.rays import MISS, PeriodicRayScene, RayScene


def brute_force(tris: np.ndarray, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Möller–Trumbore in float64 over all (ray, triangle) pairs.

    Returns the nearest id (-1 for none), its t (inf for none) and, per ray, the
    smallest barycentric margin of the nearest hit (how far inside the triangle
    the hit lies) and the gap to the second-nearest hit, to skip ambiguous rays.
    """
    v0, v1, v2 = tris[:, 0], tris[:, 1], tris[:, 2]
    e1, e2 = v1 - v0, v2 - v0
    p = np.cross(d[:, None, :], e2[None, :, :])
    det = np.einsum("tk,ntk->nt", e1, p)
    inv = np.divide(1.0, det, out=np.full_like(det, np.inf), where=det != 0)
    s = o[:, None, :] - v0[None, :, :]
    u = np.einsum("ntk,ntk->nt", s, p) * inv
    q = np.cross(s, e1[None, :, :])
    v = np.einsum("nk,ntk->nt", d, q) * inv
    t = np.einsum("tk,ntk->nt", e2, q) * inv
    ok = (det != 0) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
    tt = np.where(ok, t, np.inf)
    order = np.argsort(tt, axis=1)
    first = order[:, 0]
    rows = np.arange(o.shape[0])
    t1 = tt[rows, first]
    t2 = tt[rows, order[:, 1]] if tris.shape[0] > 1 else np.full(o.shape[0], np.inf)
    ids = np.where(np.isfinite(t1), first, -1)
    margin = np.minimum(np.minimum(u, v), 1 - u - v)[rows, first]
    gap = np.where(np.isfinite(t1), t2 - np.where(np.isfinite(t1), t1, 0.0), np.inf)
    return ids, t1, np.where(np.isfinite(t1), margin, np.inf), gap


def random_soup(rng: np.random.Generator, n: int, size: float = 0.3) -> np.ndarray:
    centres = rng.uniform(-1, 1, (n, 1, 3))
    return centres + rng.normal(scale=size, size=(n, 3, 3))


def test_single_triangle_closed_form():
    tri = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])
    scene = RayScene(tri)
    o = np.array([[0.2, 0.2, 2.0], [0.2, 0.2, -3.0], [0.8, 0.8, 2.0], [0.2, 0.2, 2.0], [0.2, 0.2, 2.0]])
    d = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 2.0], [0.0, 0.0, -1.0], [0.0, 0.0, 1.0], [0.0, 0.0, -0.5]])
    ids, t = scene.intersect(o, d)
    np.testing.assert_array_equal(ids, [0, 0, MISS, MISS, 0])
    # t is in units of |direction|: 2 / 1, 3 / 2, none, none (pointing away), 2 / 0.5
    np.testing.assert_allclose(t, [2.0, 1.5, np.inf, np.inf, 4.0], rtol=1e-14)
    np.testing.assert_allclose(scene.normals, [[0.0, 0.0, 1.0]])
    assert scene.areas[0] == pytest.approx(0.5)
    # tfar cuts the search: hits beyond it are misses
    ids, t = scene.intersect(o[:1], d[:1], tfar=1.9)
    assert ids[0] == MISS and t[0] == np.inf
    ids, t = scene.intersect(o[:1], d[:1], tfar=2.1)
    assert ids[0] == 0


def test_matches_brute_force_on_random_soup(rng):
    tris = random_soup(rng, 60)
    scene = RayScene(tris)
    n = 3000
    o = rng.uniform(-2.5, 2.5, (n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    ids, t = scene.intersect(o, d)
    bf_ids, bf_t, margin, gap = brute_force(tris, o, d)
    # Embree works in float32: rays that graze an edge (barycentric margin
    # < 1e-4) or whose two nearest hits are within 1e-4 may legitimately
    # differ; everything else must agree exactly in id, and in t to float64
    # rounding (t is refined against the triangle plane).
    clear = ((margin > 1e-4) | ~np.isfinite(bf_t)) & (gap > 1e-4)
    assert clear.sum() > 0.9 * n
    np.testing.assert_array_equal(ids[clear], bf_ids[clear])
    hit = clear & (bf_ids >= 0)
    assert hit.sum() > 200
    np.testing.assert_allclose(t[hit], bf_t[hit], rtol=1e-9, atol=1e-12)
    # without refinement, Embree's float32 t is good to ~1e-6 relative
    _, t32 = scene.intersect(o, d, refine=False)
    np.testing.assert_allclose(t32[hit], bf_t[hit], rtol=1e-5)


def test_refined_hit_points_lie_on_the_plane_far_from_origin(rng):
    # A triangle 1e3 units from the origin, rays from 50 units away: float32 t
    # would put hit points ~1e-4 off the plane; refined ones are on it to 1e-12.
    tri = np.array([[[1000.0, 0.0, 0.0], [1001.0, 0.0, 0.0], [1000.0, 1.0, 0.3]]])
    scene = RayScene(tri)
    n = 500
    targets = tri[0, 0] + rng.uniform(0.05, 0.45, (n, 1)) * (tri[0, 1] - tri[0, 0]) + rng.uniform(
        0.05, 0.45, (n, 1)
    ) * (tri[0, 2] - tri[0, 0])
    o = targets + rng.normal(size=(n, 3)) * 50.0
    d = targets - o
    ids, t = scene.intersect(o, d)
    assert np.all(ids == 0)
    pts = o + t[:, None] * d
    dist = np.abs((pts - tri[0, 0]) @ scene.normals[0])
    assert dist.max() < 1e-9
    np.testing.assert_allclose(t, 1.0, rtol=1e-12)


def test_workers_and_chunks_do_not_change_results(rng):
    tris = random_soup(rng, 40)
    scene = RayScene(tris)
    o = rng.uniform(-2, 2, (5000, 3))
    d = rng.normal(size=(5000, 3))
    a = scene.intersect(o, d)
    b = scene.intersect(o, d, workers=2, chunk=333)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])


def test_offset_origin_does_not_rehit_its_surface(rng):
    # Continue paths from hit points as the reference does: offset along the
    # normal to the side the ray leaves to. No ray may hit its own triangle
    # again; yet the offset is small enough that rays sent back from the
    # offset point still find the triangle (at t = offset).
    scale = 200.0  # coordinates far from 0 make float32 rounding larger
    tri = np.array([[[scale, scale, scale], [scale + 1, scale, scale + 0.2], [scale, scale + 1, scale - 0.1]]])
    scene = RayScene(tri)
    n = 20000
    uv = rng.uniform(0.05, 0.45, (n, 2))  # away from the edges
    p = tri[0, 0] + uv[:, :1] * (tri[0, 1] - tri[0, 0]) + uv[:, 1:] * (tri[0, 2] - tri[0, 0])
    normal = scene.normals[0]
    eps = scene.offset_distance()
    assert 1e-5 * scale > eps > 1e-7 * scale
    d = rng.normal(size=(n, 3))
    d *= np.sign(d @ normal)[:, None]  # leave on the +normal side
    ids, _ = scene.intersect(p + eps * normal, d)
    assert np.all(ids == MISS)
    ids, t = scene.intersect(p + eps * normal, np.broadcast_to(-normal, (n, 3)))
    assert np.all(ids == 0)
    np.testing.assert_allclose(t, eps, rtol=1e-6)


def test_empty_scene_and_bad_input():
    scene = RayScene(np.zeros((0, 3, 3)))
    ids, t = scene.intersect(np.zeros((4, 3)), np.ones((4, 3)))
    assert np.all(ids == MISS) and np.all(np.isinf(t))
    with pytest.raises(ValueError, match=r"\(T, 3, 3\)"):
        RayScene(np.zeros((2, 3)))
    with pytest.raises(ValueError, match="NaN"):
        RayScene(np.full((1, 3, 3), np.nan))
    with pytest.raises(ValueError, match="shape of origins"):
        RayScene(np.eye(3)[None]).intersect(np.zeros((2, 3)), np.zeros((3, 3)))


# --------------------------------------------------------------------------
# periodic scenes
# --------------------------------------------------------------------------


def test_periodic_matches_explicitly_tiled_scene(rng):
    # Random triangles in a 1 x 0.7 cell (some straddling its sides) against
    # the same triangles copied 41 x 41 times: rays from inside the central
    # cell must find the same triangle (modulo T) at the same distance.
    period = (1.0, 0.7)
    n_tri = 25
    centres = rng.uniform([0, 0, 0], [period[0], period[1], 0.5], (n_tri, 1, 3))
    tris = centres + rng.normal(scale=0.08, size=(n_tri, 3, 3))
    tris[..., 2] = np.clip(tris[..., 2], -0.1, 0.6)
    pscene = PeriodicRayScene(tris, period=period)
    k = 20
    offsets = np.array([(i * period[0], j * period[1], 0.0) for i in range(-k, k + 1) for j in range(-k, k + 1)])
    big = RayScene((tris[None] + offsets[:, None, None, :]).reshape(-1, 3, 3))
    n = 2000
    o = np.column_stack([rng.uniform(0, period[0], n), rng.uniform(0, period[1], n), rng.uniform(-0.1, 0.6, n)])
    d = rng.normal(size=(n, 3))
    d[:, 2] *= 0.3  # flatter rays cross several cells
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    hits = pscene.intersect(o, d)
    ids, t = big.intersect(o, d)
    assert not hits.truncated.any()
    # the explicit tiling is finite: only compare rays that hit something or
    # leave the layer's z range while still over it
    z_lo, z_hi = pscene.z_range
    t_layer = np.where(d[:, 2] > 0, (z_hi - o[:, 2]) / d[:, 2], (z_lo - o[:, 2]) / d[:, 2])
    inside = np.minimum(t, t_layer) * np.linalg.norm(d[:, :2], axis=1) < 0.6 * k * min(period)
    assert inside.sum() > 0.95 * n
    np.testing.assert_array_equal(hits.tri_id[inside], np.where(ids[inside] >= 0, ids[inside] % n_tri, MISS))
    assert 0.2 * n < np.sum(inside & (ids >= 0)) < 0.9 * n  # both hits and misses are compared
    np.testing.assert_allclose(hits.t[inside], t[inside], rtol=1e-9, atol=1e-9)
    # hit points are mapped into the base cell
    inside &= ids >= 0
    p = hits.points[inside]
    assert np.all((p[:, 0] >= 0) & (p[:, 0] < period[0]) & (p[:, 1] >= 0) & (p[:, 1] < period[1]))
    expected = o[inside] + t[inside, None] * d[inside]
    expected[:, 0] = np.mod(expected[:, 0], period[0])
    expected[:, 1] = np.mod(expected[:, 1], period[1])
    np.testing.assert_allclose(p, expected, atol=1e-9)
    # rays that leave through the top or bottom miss
    up = pscene.intersect(np.array([[0.5, 0.3, 0.65]]), np.array([[0.0, 0.0, 1.0]]))
    assert up.tri_id[0] == MISS and not up.truncated[0]


def test_periodic_slanted_ray_to_a_plane_and_truncation():
    # A horizontal square covering a quarter of the cell at z = 0: a ray from
    # z = 1 at 45° in x crosses cells until it reaches z = 0 at x = x0 + 1,
    # which lies over the square after wrapping.
    sq = np.array(
        [[[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.5, 0.5, 0.0]], [[0.0, 0.0, 0.0], [0.5, 0.5, 0.0], [0.0, 0.5, 0.0]]]
    )
    tris = np.concatenate([sq, sq + [0.0, 0.0, 1.0]])
    scene = PeriodicRayScene(tris, period=(1.0, 1.0))
    s = 1 / math.sqrt(2)
    h = scene.intersect(np.array([[0.2, 0.2, 0.999]]), np.array([[s, 0.0, -s]]))
    # lands at x = 0.2 + 0.999 = 1.199 -> 0.199 after wrapping, inside the square
    assert h.tri_id[0] in (0, 1)
    assert h.t[0] == pytest.approx(0.999 * math.sqrt(2), rel=1e-12)
    np.testing.assert_allclose(h.points[0], [0.199, 0.2, 0.0], atol=1e-12)
    # a horizontal ray between the planes never hits or leaves: truncated, not a silent miss
    h = scene.intersect(np.array([[0.2, 0.2, 0.5]]), np.array([[1.0, 0.0, 0.0]]), max_segments=50)
    assert h.truncated[0] and h.tri_id[0] == MISS


def test_periodic_rejects_geometry_beyond_one_period():
    tri = np.array([[[0.0, 0.0, 0.0], [2.5, 0.0, 0.0], [0.0, 0.5, 0.0]]])
    with pytest.raises(ValueError, match="within one period"):
        PeriodicRayScene(tri, period=(1.0, 1.0))
    with pytest.raises(ValueError, match="period"):
        PeriodicRayScene(tri, period=(1.0, 0.0))


def test_degenerate_triangles_are_never_hit(rng):
    # Zero-area triangles keep their index (ids stay aligned with the input)
    # but Embree never reports them, even for rays through their line.
    line = [[0, 0, 0], [1, 0, 0], [2, 0, 0]]
    point = [[0, 0, 0], [0, 0, 0], [0, 0, 0]]
    good = [[0, 0, 1], [1, 0, 1], [0, 1, 1]]
    tris = np.array([line, point, good], dtype=float)
    scene = RayScene(tris)
    np.testing.assert_array_equal(scene.normals[:2], 0.0)
    n = 20000
    o = np.column_stack([rng.uniform(-0.5, 2.5, n), np.full(n, -1.0), np.zeros(n)])
    ids, _ = scene.intersect(o, np.tile([0.0, 1.0, 0.0], (n, 1)))
    assert np.all(ids == MISS)
    ids, _ = scene.intersect(np.array([[0.2, 0.2, 0.0]]), np.array([[0.0, 0.0, 1.0]]))
    assert ids[0] == 2


def test_count_crossings_through_a_stack_of_planes():
    from foliage_tools.geometry.rays import RayScene, count_crossings

    # five horizontal squares (two triangles each) at z = 1..5
    tris = []
    for z in range(1, 6):
        a, b, c, d = (-1, -1, z), (1, -1, z), (1, 1, z), (-1, 1, z)
        tris += [(a, b, c), (a, c, d)]
    scene = RayScene(np.array(tris, dtype=float))
    origins = np.array([[0.1, 0.2, 0.0], [0.3, -0.2, 2.5], [5.0, 5.0, 0.0]])
    counts = count_crossings(scene, origins, [(0, 0, 1), (0, 0, -1)])
    assert counts[:, 0].tolist() == [5, 3, 0] and counts[:, 1].tolist() == [0, 2, 0]
    # a ray starting on plane 3 skips its own leaf's (coplanar) triangles
    leaf = np.repeat(np.arange(5), 2)
    on = count_crossings(scene, [[0.1, 0.1, 3.0]], (0, 0, 1), skip_ids=[2], id_of_triangle=leaf)
    assert on.tolist() == [[2]]
