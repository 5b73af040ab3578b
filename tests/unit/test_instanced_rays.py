"""The two-level ray scene (foliage_tools.geometry.instanced) against a flat scene of the copied triangles.

The independent answer is :class:`RayScene` over every instance's triangles placed in the world (itself
tested against brute-force Möller–Trumbore in test_rays.py): the same first hit (instance, triangle), the
same distance and the same occlusion, ray by ray.
"""

from __future__ import annotations

import numpy as np
import pytest

from foliage_tools.geometry.instanced import InstancedRayScene
from foliage_tools.geometry.rays import RayScene


def _rotation(rng) -> np.ndarray:
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _forest(rng, n=40, shear=True):
    """Two prototypes of random small triangles, n placements: rotated, scaled per axis, sheared, translated."""
    protos = [rng.uniform(-1, 1, (t, 1, 3)) + 0.15 * rng.normal(size=(t, 3, 3)) for t in (300, 500)]
    m = np.tile(np.eye(4), (n, 1, 1))
    which = rng.integers(0, 2, n)
    for k in range(n):
        s = np.diag(rng.uniform(0.5, 2.0, 3))
        if shear:
            s[0, 1] = rng.uniform(-0.3, 0.3)
        m[k, :3, :3] = _rotation(rng) @ s
        m[k, :3, 3] = rng.uniform(-6, 6, 3)
    flat = np.concatenate([protos[p] @ m[k, :3, :3].T + m[k, :3, 3] for k, p in enumerate(which)])
    first = np.concatenate([[0], np.cumsum([len(protos[p]) for p in which])])
    return protos, m, which, flat, first


#: Rays whose hit differs between the frames, at most: float32 traversal in another frame can flip a ray
#: that grazes a triangle edge or a near-tie (measured 0 of 200 000 here, ~7e-5 in a dense stand); a wrong
#: inverse, translation or box flips most of the hits.
_FLIPS = 1e-3


def test_first_hits_and_occlusion_equal_the_copied_world(rng):
    protos, m, which, flat, first = _forest(rng)
    scene, ref = InstancedRayScene(protos, m, which), RayScene(flat)
    o = rng.uniform(-9, 9, (50_000, 3))
    d = rng.normal(size=(50_000, 3)) * rng.uniform(0.1, 3.0, (50_000, 1))  # not unit: t is in |d|
    inst, tri, t = scene.intersect(o, d)
    ref_tri, ref_t = ref.intersect(o, d)
    ids = np.where(inst >= 0, first[np.maximum(inst, 0)] + tri, -1)
    assert 0.1 < np.mean(ref_tri >= 0) < 0.9  # both hits and misses are tested
    assert np.mean(ids != ref_tri) <= _FLIPS
    same = (ids == ref_tri) & (ids >= 0)
    # the distance is refined in float64 against the hit plane in both frames
    assert np.allclose(t[same], ref_t[same], rtol=1e-9, atol=0)
    assert np.all(np.isinf(t[inst < 0]))
    assert np.mean(scene.occluded(o, d) != ref.occluded(o, d)) <= _FLIPS
    # world normals: the copied triangle's own normal, up to the orientation kept by det(A) > 0 or < 0
    n = scene.world_normals(inst[same], tri[same])
    assert np.allclose(np.abs(np.einsum("ij,ij->i", n, ref.normals[ref_tri[same]])), 1.0, atol=1e-9)


def test_tfar_stops_the_search(rng):
    protos, m, which, flat, first = _forest(rng, n=20, shear=False)
    scene, ref = InstancedRayScene(protos, m, which), RayScene(flat)
    o = rng.uniform(-9, 9, (20_000, 3))
    d = rng.normal(size=(20_000, 3))
    far = rng.uniform(0.0, 6.0, 20_000)
    inst, tri, t = scene.intersect(o, d, tfar=far)
    ref_tri, ref_t = ref.intersect(o, d, tfar=far)
    ids = np.where(inst >= 0, first[np.maximum(inst, 0)] + tri, -1)
    assert np.mean(ids != ref_tri) <= _FLIPS
    assert np.all(t[inst >= 0] <= far[inst >= 0] * (1 + 1e-6))


def test_a_stand_of_one_prototype_is_traced_as_far_as_the_first_hit(rng):
    # a 12 x 12 grid of overlapping crowns: a ray crosses many boxes, and the waves must still find the nearest
    proto = rng.normal(size=(2000, 1, 3)) * 1.5 + [0, 0, 4] + 0.08 * rng.normal(size=(2000, 3, 3))
    xs, ys = np.meshgrid(np.arange(12) * 4.0, np.arange(12) * 4.0)
    m = np.tile(np.eye(4), (144, 1, 1))
    m[:, 0, 3], m[:, 1, 3] = xs.ravel(), ys.ravel()
    scene = InstancedRayScene([proto], m, np.zeros(144, np.int64))
    ref = RayScene(np.concatenate([proto + m[k, :3, 3] for k in range(144)]))
    o = rng.uniform([-4, -4, 0], [48, 48, 9], (30_000, 3))
    d = rng.normal(size=(30_000, 3))
    inst, tri, _ = scene.intersect(o, d)
    ref_tri, _ = ref.intersect(o, d)
    ids = np.where(inst >= 0, inst * 2000 + tri, -1)
    assert np.mean(ref_tri >= 0) > 0.3  # a third of the rays hit a crown
    assert np.mean(ids != ref_tri) <= _FLIPS


def test_rays_that_miss_every_box_and_empty_prototypes():
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], dtype=float)
    m = np.tile(np.eye(4), (2, 1, 1))
    m[1, :3, 3] = (5, 0, 0)
    scene = InstancedRayScene([tri, np.zeros((0, 3, 3))], m, [0, 1])  # instance 1 places nothing
    inst, t_id, t = scene.intersect([[0.2, 0.2, 1], [5.2, 0.2, 1], [0.2, 0.2, -1]], [[0, 0, -1], [0, 0, -1], [0, 0, -1]])
    assert inst.tolist() == [0, -1, -1] and t_id.tolist() == [0, -1, -1]
    assert t[0] == pytest.approx(1.0) and np.isinf(t[1:]).all()
    assert scene.occluded([[0.2, 0.2, 1], [9, 9, 9]], [[0, 0, -1], [1, 0, 0]]).tolist() == [True, False]


def test_a_singular_transform_is_refused():
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], dtype=float)
    m = np.eye(4)[None].copy()
    m[0, 2, 2] = 0.0
    with pytest.raises(ValueError, match="singular"):
        InstancedRayScene([tri], m, [0])
