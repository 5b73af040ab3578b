"""s_max's scattered light with the scatterers lit by the leaves (lighting.scatterer_sun, boulanger.higher_orders).

The weighted octant means are checked against a brute-force numpy evaluation of their definition; the scattered
light of a uniform ball of random cards against the Monte Carlo reference (the project's truth), where the
thesis' eq. (5.24) reads 0.59 of it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from foliage_tools.lighting.envelope import boulanger as bl
from foliage_tools.lighting import direct, reference
from foliage_tools.lighting import envelope
from foliage_tools.lighting.optics import LeafOptics
from foliage_tools.lighting.envelope.scatterer_sun import scatterer_transmission

UP = (0.0, 0.0, 1.0)
SUN = np.array([math.cos(math.radians(60)) * math.cos(math.radians(45)),
                math.cos(math.radians(60)) * math.sin(math.radians(45)), math.sin(math.radians(60))])


def brute_force(centres, lit, tau, leaf_size, up=UP):
    """eq. (1) of lighting.scatterer_sun written out: every pair, octant = the nearest sample direction."""
    dirs = envelope.sample_directions(up)
    n = len(centres)
    sums, weights = np.zeros((n, 8)), np.zeros((n, 8))
    for i in range(n):
        d = centres - centres[i]
        r = np.linalg.norm(d, axis=1)
        w = np.exp(-tau * r) / np.maximum(r, leaf_size / 2) ** 2
        w[i] = 0.0
        j = np.argmax(d @ dirs.T, axis=1)
        for k in range(8):
            sums[i, k] = (w * (j == k)) @ lit
            weights[i, k] = (w * (j == k)).sum()
    return sums, weights


def test_octant_means_are_their_definition():
    rng = np.random.default_rng(3)
    x = rng.uniform(-1, 1, size=(400, 3))
    lit = rng.uniform(size=400)
    for up in ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0), (0.3, -0.2, 0.9)):
        sums, weights = brute_force(x, lit, 1.7, 0.1, up)
        got = scatterer_transmission(x, lit, 1.7, up=up, leaf_size=0.1)
        full = weights > 0
        np.testing.assert_allclose(got[full], sums[full] / weights[full], rtol=1e-12, atol=1e-14)
        # an empty octant takes the leaf's weighted mean over all octants
        empty = ~full
        assert empty.any()
        rows = np.nonzero(empty)[0]
        np.testing.assert_allclose(got[empty], (sums.sum(1) / weights.sum(1))[rows], rtol=1e-12)


def test_uniform_lit_fraction_is_returned_exactly():
    """Any weighted mean of a constant is the constant (also through the near + subset path)."""
    x = np.random.default_rng(4).normal(size=(3000, 3))
    for max_pairs in (10**9, 3000 * 300):
        got = scatterer_transmission(x, np.full(3000, 0.37), 2.0, leaf_size=0.05, max_pairs=max_pairs)
        np.testing.assert_allclose(got, 0.37, rtol=1e-12)


def test_subsampled_far_field_estimates_the_full_sums():
    """Above max_pairs: exact 128 nearest + a uniform subset beyond. Against the full sums on a 3000-leaf ball
    with a lit fraction that varies smoothly across it (a shadowed side): the subset is a consistent estimate,
    so its mean error falls as it grows (measured 0.017 / 0.008 mean abs at 300 / 800 pairs per leaf); the
    bound 0.03 at 800 is four times that, and fails for a biased far field (e.g. a missing n/m weight)."""
    rng = np.random.default_rng(5)
    d = rng.normal(size=(3000, 3))
    x = d / np.linalg.norm(d, axis=1, keepdims=True) * rng.uniform(size=(3000, 1)) ** (1 / 3)
    lit = np.clip(0.5 + 0.5 * x[:, 2], 0, 1)
    full = scatterer_transmission(x, lit, 1.0, leaf_size=0.05)
    sub = scatterer_transmission(x, lit, 1.0, leaf_size=0.05, max_pairs=3000 * 800)
    assert np.mean(np.abs(sub - full)) < 0.03


def test_hard_cases_are_finite():
    one = scatterer_transmission(np.zeros((1, 3)), np.array([0.4]), 1.0, leaf_size=0.1)
    np.testing.assert_allclose(one, 0.4)  # no neighbour at all: its own lit fraction
    same = scatterer_transmission(np.zeros((5, 3)), np.linspace(0, 1, 5), 1.0, leaf_size=0.1)
    assert np.all(np.isfinite(same)) and np.all((same >= 0) & (same <= 1))
    far = scatterer_transmission(np.array([[0.0, 0, 0], [1e6, 0, 0]]), np.array([0.0, 1.0]), 5.0, leaf_size=0.1)
    np.testing.assert_allclose(far, [[0.0] * 8, [1.0] * 8])  # weights underflow: each its own
    assert scatterer_transmission(np.zeros((0, 3)), np.zeros(0), 1.0, leaf_size=0.1).shape == (0, 8)
    with pytest.raises(ValueError):
        scatterer_transmission(np.zeros((2, 3)), np.array([0.5, 1.5]), 1.0, leaf_size=0.1)
    with pytest.raises(ValueError):
        scatterer_transmission(np.zeros((2, 3)), np.array([0.5, 0.5]), math.nan, leaf_size=0.1)


def test_no_leaves_between_is_pass_through():
    """DESIGN.md section 4, pass-through at density 0: τ = 0 scatters nothing, finite, with lit scatterers."""
    nrm = np.tile([0.0, 0.0, 1.0], (3, 1))
    res = bl.solve(nrm, np.ones((3, 8)), 0.0, up=UP, params=bl.BoulangerParams(
        sun_direction=tuple(SUN), reflectance=0.4, transmittance=0.4), scatterer_sun=np.full((3, 8), 0.5),
        all_orders=True)
    assert np.all(res.e_scattered == 0) and np.all(np.isfinite(res.e_direct))
    with pytest.raises(ValueError):
        bl.solve(nrm, np.ones((3, 8)), 1.0, up=UP, params=bl.BoulangerParams(
            sun_direction=tuple(SUN), reflectance=0.4, transmittance=0.4), scatterer_sun=np.full((3, 8), 1.5))


def test_higher_orders_series():
    """1/(1 - ω p) is the sum of the orders' geometric series, finite at ω = p = 1."""
    w = np.array([0.1, 0.5, 0.9])
    np.testing.assert_allclose(bl.higher_orders(w, 0.6), sum((w * 0.6) ** k for k in range(200)), rtol=1e-12)
    assert np.isfinite(bl.higher_orders(1.0, 1.0))
    assert bl.recollision_probability(np.ones((4, 8))) == 0.0  # nothing in the way: every scattered ray escapes


def _ball(n, side, seed):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    c = d / np.linalg.norm(d, axis=1, keepdims=True) * rng.uniform(size=(n, 1)) ** (1 / 3)
    nrm = rng.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    a = np.cross(nrm, rng.normal(size=(n, 3)))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = np.cross(nrm, a)
    p = [c + side / 2 * (sa * a + sb * b) for sa, sb in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    tris = np.concatenate([np.stack([p[0], p[1], p[2]], 1), np.stack([p[0], p[2], p[3]], 1)])
    return c, nrm, np.full(n, side * side), tris, np.concatenate([np.arange(n), np.arange(n)])


@pytest.fixture(scope="module")
def dense_ball():
    """3000 cards of 0.1 in a unit ball: LAD 7.2, τR = 3.6 (a dense crown, where eq. (5.24) is 0.59 of the truth)."""
    c, nrm, area, tris, leaf = _ball(3000, 0.1, 1)
    env = envelope.solve(c, nrm, area, up=UP)
    lit = direct.solve(direct.DirectInputs(tris, leaf, len(c), SUN), direct.DirectParams(samples_per_leaf=256)).lit_fraction
    return c, nrm, area, tris, leaf, env, lit


def _scattered(dense_ball, albedo, *, leaves: bool, paths: int):
    c, nrm, area, tris, leaf, env, lit = dense_ball
    r = t = albedo / 2
    t_bar = scatterer_transmission(c, lit, env.tau, up=UP, leaf_size=0.1) if leaves else None
    model = bl.solve(nrm, env.smax, env.tau, up=UP, params=bl.BoulangerParams(
        sun_direction=tuple(SUN), reflectance=(r,) * 3, transmittance=(t,) * 3), scatterer_sun=t_bar,
        all_orders=leaves).e_scattered[:, 1].astype(float)
    ref = reference.solve(reference.ReferenceInputs(
        triangles=tris, leaf_of_triangle=leaf, leaf_area=area, optics=LeafOptics(np.full(3, r), np.full(3, t)),
        sun_direction=SUN), reference.ReferenceParams(paths=paths, seed=0)).e_scattered[:, 1]
    return model, ref, c @ SUN


def test_one_bounce_with_lit_scatterers_matches_the_reference_in_a_dense_ball(dense_ball):
    """Albedo 0.02: the light is single scattering (the second order ~ωp = 1.6 % of it). The crown mean and the
    shaded half (height toward the sun < 0) within 12 % of the reference: the 8 octant bins of eq. (5.11) err by
    −26…+13 % for a single normal at the centre of a ball (test_boulanger's continuum check) but are exact for
    isotropic light averaged over uniform normals, so over a crown they leave a few per cent; the crown mean's
    reference noise is ~0.1 %. Measured 1.02 / 1.09 (shaded) with the lit scatterers; the thesis' eq. (5.24)
    reads 0.59 / 0.69 (and 1.57 in the deepest shade), outside the bound."""
    model, ref, height = _scattered(dense_ball, 0.02, leaves=True, paths=2_000_000)
    assert 0.88 <= model.mean() / ref.mean() <= 1.12
    shaded = height < 0
    assert 0.88 <= model[shaded].mean() / ref[shaded].mean() <= 1.12
    paper, _, _ = _scattered(dense_ball, 0.02, leaves=False, paths=2)
    assert paper.mean() / ref.mean() < 0.75  # the finding this fixes (it would pass the bound if it were wrong)


def test_every_order_matches_the_reference_at_high_albedo(dense_ball):
    """Albedo 0.9, τR = 3.6: scattered light of every order is 3.6x the first (p = 0.81). The crown mean within
    15 %: the one-bounce's 12 % above plus the spectral-invariant assumption (each order spread like the last),
    which the review cited in boulanger.higher_orders reports good to a few per cent for a canopy's totals.
    Measured 1.01; one bounce alone reads 0.28."""
    model, ref, _ = _scattered(dense_ball, 0.9, leaves=True, paths=1_000_000)
    assert 0.85 <= model.mean() / ref.mean() <= 1.15
