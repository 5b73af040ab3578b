"""Final gather (foliage_tools.lighting.gather) against closed forms and the Monte Carlo reference.

Bounds on a count of gather rays that hit a card use the binomial spread of
independent cosine-distributed rays, σ = sqrt(F (1 - F) / n) for a hit
probability F (the view factor): the lattice directions spread more evenly
than independent ones, so 4σ is a loose but safe bound.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from foliage_tools.lighting.gather import GatherInputs, GatherParams, solve
from foliage_tools.lighting.optics import LeafOptics
from foliage_tools.lighting.reference import ReferenceParams
from foliage_tools.lighting.reference import solve as reference_solve

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_reference import card, crown, view_factor_parallel_squares  # noqa: E402


@pytest.mark.parametrize("gap", [0.05, 0.3])
def test_light_transmitted_by_a_lit_card_onto_the_card_below(gap):
    # Card A (side 1) at height `gap` over card B, sun tilted 30° in the x-z plane; leaves transmit
    # (t per channel) and do not reflect. A is fully lit, so its underside sends t cos θ / π (radiance);
    # B's upper face sees A over the view factor F of two opposed squares, so
    # E_scattered(B) = t cos θ F (its lower face sees nothing), and A's lower face sees B's sunlit top,
    # which reflects nothing: E_scattered(A) = 0 exactly. Bound: 4σ of the binomial count of the
    # 512 upward rays that hit A (module docstring), and the mean of 20 seeds within 4σ/sqrt(20).
    theta = math.radians(30.0)
    sun = np.array([math.sin(theta), 0.0, math.cos(theta)])
    t = np.array([0.1, 0.5, 0.9])
    tris = np.concatenate([card([0, 0, gap], [0, 0, 1], 1.0), card([0, 0, 0], [0, 0, 1], 1.0)])
    inputs = GatherInputs(tris, np.array([0, 0, 1, 1]), 2, LeafOptics(0.0, t, 0.0), sun)
    f = view_factor_parallel_squares(1.0, gap)
    expected = t * math.cos(theta) * f
    sigma = t * math.cos(theta) * math.sqrt(f * (1 - f) / 512)
    runs = np.array([solve(inputs, GatherParams(1024, seed=s)).e_scattered for s in range(20)])
    assert np.all(runs[:, 0] == 0.0)
    assert np.all(np.abs(runs[:, 1] - expected) <= 4 * sigma), (runs[:, 1], expected)
    assert np.all(np.abs(runs[:, 1].mean(axis=0) - expected) <= 4 * sigma / math.sqrt(20))


def test_higher_orders_come_from_the_volume_method_at_the_hit_leaf():
    # An edge-on sun (along x, cards normal to z) lights neither card: no first bounce. With the
    # volume method's E_scattered R_A, R_B (both faces) split evenly between the faces, a face of
    # the other card sends (r R/2 + t R/2)/π, so E(B) = (r + t) R_A F / 2 and E(A) = (r + t) R_B F / 2.
    # Bound as above (the hit count is the only random part).
    r, t = np.array([0.3, 0.2, 0.1]), np.array([0.2, 0.3, 0.4])
    tris = np.concatenate([card([0, 0, 0.2], [0, 0, 1], 1.0), card([0, 0, 0], [0, 0, 1], 1.0)])
    rest = np.array([[0.2, 0.1, 0.05], [0.4, 0.3, 0.2]])
    res = solve(GatherInputs(tris, np.array([0, 0, 1, 1]), 2, LeafOptics(r, t, 0.0), (1.0, 0.0, 0.0), rest=rest),
                GatherParams(2048, seed=1))
    f = view_factor_parallel_squares(1.0, 0.2)
    sigma = math.sqrt(f * (1 - f) / 1024)
    np.testing.assert_allclose(res.e_scattered[1], (r + t) * rest[0] * f / 2, rtol=4 * sigma / f)
    np.testing.assert_allclose(res.e_scattered[0], (r + t) * rest[1] * f / 2, rtol=4 * sigma / f)
    assert np.all(res.e_first == 0.0)


def test_agrees_with_the_reference_on_a_crown_of_dark_leaves():
    # With the reference's own E_scattered as the higher orders, the gather must reproduce it: the
    # first bounce is exact in expectation, and with albedo 0.1 the higher orders (and the even split
    # between faces they are taken with) are ~1 % of the scattered light. Leaf by leaf the relative
    # RMS difference is about sqrt(noise_gather² + noise_ref²); bound 1.3x that. The means agree
    # within 2 % (the split's share, and the noise of a mean over 300 leaves ~0.5 %).
    rng = np.random.default_rng(21)
    inputs = crown(300, rng, side=0.15, optics=LeafOptics(0.05, 0.05, 0.2))
    ref = reference_solve(inputs, ReferenceParams(paths=2_000_000, seed=2))
    g = solve(GatherInputs(inputs.triangles, inputs.leaf_of_triangle, inputs.n_leaves, inputs.optics,
                           inputs.sun_direction, rest=ref.e_scattered), GatherParams(512, seed=3))
    diff = np.linalg.norm(g.e_scattered - ref.e_scattered) / np.linalg.norm(ref.e_scattered)
    assert diff <= 1.3 * math.hypot(g.noise_rel, ref.noise_rel), (diff, g.noise_rel, ref.noise_rel)
    assert np.all(np.abs(g.e_scattered.mean(axis=0) / ref.e_scattered.mean(axis=0) - 1) < 0.02)
    # the first bounce is most of it here, and the higher orders add, never subtract
    assert np.all(g.e_first.sum(axis=0) > 0.8 * g.e_scattered.sum(axis=0))
    assert np.all(g.e_first <= g.e_scattered + 1e-15)


def test_bitwise_reproducible_whatever_the_workers_and_checks_its_input():
    rng = np.random.default_rng(2)
    inputs = crown(60, rng, optics=LeafOptics(0.2, 0.2, 0.2))
    gi = GatherInputs(inputs.triangles, inputs.leaf_of_triangle, inputs.n_leaves, inputs.optics, inputs.sun_direction)
    a = solve(gi, GatherParams(64, seed=4, workers=1))
    b = solve(gi, GatherParams(64, seed=4, workers=2))
    np.testing.assert_array_equal(a.e_scattered, b.e_scattered)
    assert np.all(np.isfinite(a.e_scattered)) and np.all(a.e_scattered >= 0)
    with pytest.raises(ValueError, match="multiple of 4"):
        GatherParams(rays_per_leaf=6)
    with pytest.raises(ValueError, match="rest"):
        GatherInputs(inputs.triangles, inputs.leaf_of_triangle, inputs.n_leaves, inputs.optics, inputs.sun_direction,
                     rest=np.zeros((3, 3)))
