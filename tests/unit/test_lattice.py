"""D3Q19 lattice and relighting hull (foliage_tools.lighting.lb.lattice)."""

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import ConvexHull

from foliage_tools.lighting.lb import lattice as L

unit_vectors = st.tuples(*[st.floats(-1, 1, allow_nan=False)] * 3).filter(lambda v: np.linalg.norm(v) > 1e-3)


def test_nineteen_directions_in_the_documented_order():
    c = L.DIRECTIONS
    assert c.shape == (19, 3) and L.Q == 19
    assert tuple(c[0]) == (0, 0, 0)  # rest first
    assert len({tuple(v) for v in c}) == 19
    # 1..6 axial (|c|^2 = 1), 7..18 non-axial (|c|^2 = 2): the non-corner points of the unit cube
    assert ((c[1:7] ** 2).sum(axis=1) == 1).all()
    assert ((c[7:] ** 2).sum(axis=1) == 2).all()
    assert [tuple(v) for v in c[1:7]] == [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]
    assert L.direction_index((0, 0, -1)) == 6
    with pytest.raises(ValueError, match="not a D3Q19"):
        L.direction_index((1, 1, 1))


def test_multiplicities_come_from_the_4d_projection():
    # geist2008 sec. 2.2: the 24 4D points with two ±1 entries, fourth component dropped
    counts = {}
    for a, b in itertools.combinations(range(4), 2):
        for sa, sb in itertools.product((1, -1), repeat=2):
            p = np.zeros(4, int)
            p[a], p[b] = sa, sb
            counts[tuple(p[:3])] = counts.get(tuple(p[:3]), 0) + 1
    assert sum(counts.values()) == 24
    for i, c in enumerate(L.DIRECTIONS):
        assert L.MULTIPLICITY[i] == counts.get(tuple(c), 0)
    # axial double weight
    assert (L.MULTIPLICITY[1:7] == 2).all() and (L.MULTIPLICITY[7:] == 1).all() and L.MULTIPLICITY[0] == 0


def test_weights_sum_and_values_as_in_the_paper():
    # geist2008 eqs. (6)-(8): 1/12 axial, 1/24 non-axial; total 24/24 = 1 (exact in binary up to 1 ulp)
    assert L.MULTIPLICITY.sum() == 24
    assert L.WEIGHTS.sum() == pytest.approx(1.0, abs=1e-15)
    np.testing.assert_array_equal(L.WEIGHTS[1:7], 1 / 12)
    np.testing.assert_array_equal(L.WEIGHTS[7:], 1 / 24)


def test_lattice_is_symmetric_and_isotropic_to_second_order():
    w, c = L.WEIGHTS, L.DIRECTIONS.astype(float)
    np.testing.assert_allclose(w @ c, 0.0, atol=1e-15)  # sum w_i c_i = 0
    np.testing.assert_allclose(np.einsum("i,ij,ik->jk", w, c, c), np.eye(3) / 2, atol=1e-15)
    for i in range(19):
        assert (c[L.OPPOSITE[i]] == -c[i]).all()
    np.testing.assert_allclose(np.linalg.norm(L.UNIT_DIRECTIONS[1:], axis=1), 1.0, rtol=1e-15)


@pytest.mark.parametrize("name", ["DIRECTIONS", "MULTIPLICITY", "WEIGHTS", "UNIT_DIRECTIONS", "OPPOSITE", "HULL_TRIANGLES", "STEP_LENGTHS", "ORDINATE_WEIGHTS"])
def test_tables_are_immutable(name):
    arr = getattr(L, name)
    with pytest.raises(ValueError):
        arr[0] = arr[1]


def test_hull_has_32_triangles_that_are_faces():
    pts = L.UNIT_DIRECTIONS[1:]
    assert ConvexHull(pts).simplices.shape == (32, 3)  # steele2010 sec. 3.1
    tris = L.HULL_TRIANGLES
    assert tris.shape == (32, 3) and tris.min() >= 1 and tris.max() <= 18
    assert len({tuple(sorted(t)) for t in tris}) == 32
    for t in tris:
        v = L.UNIT_DIRECTIONS[t]
        n = np.cross(v[1] - v[0], v[2] - v[0])
        # outward and supporting: every unit direction lies on or behind the face plane
        assert n @ v[0] > 0
        assert (pts @ n <= n @ v[0] + 1e-12).all()
    # every direction is a vertex; Euler: 18 - 48 + 32 = 2
    edges = {tuple(sorted(e)) for t in tris for e in itertools.combinations(t, 2)}
    assert len(set(tris.ravel())) == 18 and len(edges) == 48


@pytest.mark.parametrize("k", range(1, 19))
def test_weights_of_a_lattice_direction_select_it(k):
    idx, w = L.barycentric_weights(L.DIRECTIONS[k])
    weights = dict(zip(idx, w))
    assert weights.get(k, 0.0) == pytest.approx(1.0, abs=1e-12)


@settings(max_examples=200, deadline=None)
@given(unit_vectors)
def test_barycentric_weights_reproduce_the_direction(d):
    idx, w = L.barycentric_weights(d)
    w = np.array(w)
    assert (w >= 0).all() and w.sum() == pytest.approx(1.0, abs=1e-12)
    hit = w @ L.UNIT_DIRECTIONS[list(idx)]
    d = np.asarray(d) / np.linalg.norm(d)
    # the hit point is on the ray: parallel to d, same orientation (round-off only)
    np.testing.assert_allclose(np.cross(hit, d), 0.0, atol=1e-12)
    assert hit @ d > 0.8  # every face plane is >= 0.816 from the origin (cuboctahedron triangles)


def _weight_vector(d):
    idx, w = L.barycentric_weights(d)
    v = np.zeros(19)
    for i, x in zip(idx, w):
        v[i] += x
    return v


def test_weights_are_continuous_across_every_hull_edge():
    # At the midpoint of each of the 48 edges, step eps to both sides (across the edge):
    # the weights over the 18 directions must differ by O(eps), not jump.
    tris = L.HULL_TRIANGLES
    edges = {tuple(sorted(e)) for t in tris for e in itertools.combinations(t, 2)}
    eps = 1e-7
    for a, b in edges:
        na, nb = L.UNIT_DIRECTIONS[a], L.UNIT_DIRECTIONS[b]
        mid = (na + nb) / 2
        across = np.cross(na - nb, mid)
        across /= np.linalg.norm(across)
        left, right = _weight_vector(mid + eps * across), _weight_vector(mid - eps * across)
        # Lipschitz constant of barycentric coordinates on these faces is < 10
        assert np.abs(left - right).max() < 20 * eps, (a, b)
        # on the edge itself only a and b carry weight, 1/2 each
        on = _weight_vector(mid)
        assert on[a] == pytest.approx(0.5, abs=1e-12) and on[b] == pytest.approx(0.5, abs=1e-12)


@settings(max_examples=100, deadline=None)
@given(unit_vectors, st.tuples(*[st.floats(-1, 1)] * 3))
def test_weights_are_lipschitz_everywhere(d, delta):
    d = np.asarray(d) / np.linalg.norm(d)
    step = 1e-6 * np.asarray(delta)
    assert np.abs(_weight_vector(d + step) - _weight_vector(d)).max() <= 20 * max(np.linalg.norm(step), 1e-15)


def test_barycentric_rejects_zero_direction():
    with pytest.raises(ValueError, match="nonzero"):
        L.barycentric_weights((0, 0, 0))


def _sphere_mean(a, b, c):
    """Mean of x^a y^b z^c over the unit sphere: 0 if any exponent is odd, else (a-1)!!(b-1)!!(c-1)!!/(a+b+c+1)!!."""
    if a % 2 or b % 2 or c % 2:
        return 0.0

    def dfact(n):
        return math.prod(range(n, 0, -2)) if n > 0 else 1

    return dfact(a - 1) * dfact(b - 1) * dfact(c - 1) / dfact(a + b + c + 1)


def test_ordinate_weights_integrate_every_polynomial_of_degree_five():
    """The ordinate weights 1/30, 1/15 are the degree-5 quadrature of the 18 unit directions (lattice docstring);
    geist2008's 1/12, 1/24 are exact only to degree 3 (the fourth moments of the velocities c_i, not of n_i)."""
    n = L.UNIT_DIRECTIONS[1:]
    w, wg = L.ORDINATE_WEIGHTS[1:], L.WEIGHTS[1:]
    assert w.sum() == pytest.approx(1.0, abs=1e-15) and L.ORDINATE_WEIGHTS[0] == 0.0
    worst_geist = 0.0
    for a, b, c in itertools.product(range(6), repeat=3):
        if a + b + c > 5:
            continue
        mono = n[:, 0] ** a * n[:, 1] ** b * n[:, 2] ** c
        assert w @ mono == pytest.approx(_sphere_mean(a, b, c), abs=1e-15), (a, b, c)
        if a + b + c <= 3:
            assert wg @ mono == pytest.approx(_sphere_mean(a, b, c), abs=1e-15), (a, b, c)
        else:
            worst_geist = max(worst_geist, abs(wg @ mono - _sphere_mean(a, b, c)))
    assert worst_geist == pytest.approx(0.05)  # sum w n_x^4 = 1/4 instead of 1/5
    # the lattice-gas condition geist2008's weights do meet: isotropic fourth moments of the velocities c_i
    c = L.DIRECTIONS[1:].astype(float)
    assert wg @ c[:, 0] ** 4 == pytest.approx(3 * wg @ (c[:, 0] ** 2 * c[:, 1] ** 2))


def test_step_lengths():
    np.testing.assert_array_equal(L.STEP_LENGTHS[1:7], 1.0)
    np.testing.assert_allclose(L.STEP_LENGTHS[7:], math.sqrt(2.0), rtol=1e-15)
    assert L.STEP_LENGTHS[0] == 0.0
    np.testing.assert_allclose(L.STEP_LENGTHS, np.linalg.norm(L.DIRECTIONS, axis=1), rtol=1e-15)
