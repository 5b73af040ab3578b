"""Triangulation and leaf extraction (foliage_tools.geometry.leaves)."""

import numpy as np
import pytest

from foliage_tools.geometry.leaves import face_values_from_triangles, leaf_components, triangulate


def test_fan_triangulation_of_mixed_faces():
    # a quad, a triangle, a degenerate 2-gon (no triangles) and a pentagon
    counts = np.array([4, 3, 2, 5])
    idx = np.array([0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13])
    tris, face = triangulate(counts, idx)
    assert tris.tolist() == [[0, 1, 2], [0, 2, 3], [4, 5, 6], [9, 10, 11], [9, 11, 12], [9, 12, 13]]
    assert face.tolist() == [0, 0, 1, 3, 3, 3]


def test_triangulation_rejects_inconsistent_counts():
    with pytest.raises(ValueError, match="faceVertexCounts sum"):
        triangulate(np.array([3, 3]), np.array([0, 1, 2]))


def _two_triangle_cards_unshared(n=3, flip_second=False):
    """Cards whose two triangles do not share vertex indices (as in converted OBJ assets)."""
    pts, tris = [], []
    for i in range(n):
        x = 2.0 * i
        quad = np.array([[x, 0, 0], [x + 1, 0, 0], [x + 1, 1, 0], [x, 1, 0]], dtype=float)
        a = [quad[0], quad[1], quad[2]]
        b = [quad[0], quad[3], quad[2]] if flip_second else [quad[0], quad[2], quad[3]]
        base = len(pts)
        pts.extend(a + b)
        tris.append([base, base + 1, base + 2])
        tris.append([base + 3, base + 4, base + 5])
    return np.array(pts), np.array(tris)


def test_cards_with_unshared_vertices_are_welded_into_leaves():
    pts, tris = _two_triangle_cards_unshared(3)
    comp = leaf_components(pts, tris)
    assert comp.areas.shape == (3,)
    np.testing.assert_allclose(comp.areas, 1.0, rtol=1e-12)
    np.testing.assert_allclose(comp.centers, [[0.5, 0.5, 0], [2.5, 0.5, 0], [4.5, 0.5, 0]], atol=1e-12)
    assert comp.triangle_leaf.tolist() == [0, 0, 1, 1, 2, 2]


def test_mixed_winding_does_not_cancel_the_normal():
    pts, tris = _two_triangle_cards_unshared(2, flip_second=True)
    comp = leaf_components(pts, tris)
    # the flipped triangle would cancel a plain sum; the leaf normal must still be ±z
    np.testing.assert_allclose(np.abs(comp.normals[:, 2]), 1.0, atol=1e-12)


def test_degenerate_triangles_are_dropped_and_counted():
    pts, tris = _two_triangle_cards_unshared(1)
    pts = np.vstack([pts, [[5, 5, 5], [5, 5, 5], [6, 6, 6]]])  # a zero-area sliver
    tris = np.vstack([tris, [[6, 7, 8]]])
    comp = leaf_components(pts, tris)
    assert comp.degenerate == 1
    assert comp.triangle_leaf.tolist() == [0, 0, -1]
    assert np.all(np.isfinite(comp.normals))


def test_face_values_take_the_first_valid_triangle():
    face_of_tri = np.array([0, 0, 1, 2, 2])
    tri_vals = np.array([-1, 7, 3, -1, -1])
    assert face_values_from_triangles(face_of_tri, tri_vals, 4).tolist() == [7, 3, -1, -1]
