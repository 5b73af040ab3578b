"""Monte Carlo reference (foliage_tools.lighting.reference) against closed forms.

Statistical bounds: where a tally is a sum of independent Bernoulli photon
contributions of fixed size, its standard deviation σ is known in closed form
from the hit probability, and the test allows 4σ (two-sided false-alarm
probability 6e-5 per check; the seeds are fixed, so the tests are
deterministic). The hit probabilities use ``result.incident``, which is the
deterministic source area (sun irradiance 1), not an estimate.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from foliage_tools.lighting.optics import LeafOptics
from foliage_tools.lighting.reference import ReferenceInputs, ReferenceParams, solve

BLACK = LeafOptics(0.0, 0.0, 0.0)


def unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def card(centre, normal, side: float) -> np.ndarray:
    """A square card of side ``side`` (2 triangles, (2, 3, 3)) centred at ``centre`` with unit normal ``normal``."""
    n = unit(normal)
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = unit(np.cross(n, helper)) * side / 2
    v = np.cross(n, u)
    c = np.asarray(centre, dtype=float)
    c00, c10, c11, c01 = c - u - v, c + u - v, c + u + v, c - u + v
    tri = np.array([[c00, c10, c11], [c00, c11, c01]])
    # orient so the geometric normal is +n (the reference is two-sided; this
    # only keeps the fixtures tidy)
    if np.dot(np.cross(tri[0, 1] - tri[0, 0], tri[0, 2] - tri[0, 0]), n) < 0:
        tri = tri[:, ::-1]
    return tri


def random_cards(n: int, side: float, rng: np.random.Generator, lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """n square cards, centres uniform in the box [lo, hi], orientations uniform (Haar)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    centres = lo + rng.random((n, 3)) * (hi - lo)
    q, r = np.linalg.qr(rng.normal(size=(n, 3, 3)))
    q = q * np.sign(np.diagonal(r, axis1=1, axis2=2))[:, None, :]
    u = q[:, :, 0] * (side / 2)
    v = q[:, :, 1] * (side / 2)
    c00, c10, c11, c01 = centres - u - v, centres + u - v, centres + u + v, centres - u + v
    tris = np.empty((2 * n, 3, 3))
    tris[0::2] = np.stack([c00, c10, c11], axis=1)
    tris[1::2] = np.stack([c00, c11, c01], axis=1)
    return tris, centres


def crown(n_leaves: int, rng: np.random.Generator, *, optics: LeafOptics, side=0.2, sun=(0.3, -0.2, 0.9), sky=0.0):
    """Cards in a ball of radius 1 above a 3-sided wooden trunk."""
    d = rng.normal(size=(n_leaves, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    tris, _ = random_cards(n_leaves, side, rng, [0, 0, 0], [0, 0, 0])
    centres = d * rng.uniform(size=(n_leaves, 1)) ** (1 / 3)
    tris = tris + np.repeat(centres, 2, axis=0)[:, None, :]
    ang = 2 * np.pi * np.arange(3) / 3
    ring = 0.08 * np.column_stack([np.cos(ang), np.sin(ang), np.zeros(3)])
    bottom, top = ring + [0, 0, -1.5], ring + [0, 0, 0.3]
    trunk = []
    for i in range(3):
        j = (i + 1) % 3
        trunk += [[bottom[i], bottom[j], top[j]], [bottom[i], top[j], top[i]]]
    tris = np.concatenate([tris, np.array(trunk)])
    leaf = np.concatenate([np.repeat(np.arange(n_leaves), 2), np.full(6, -1)])
    return ReferenceInputs(
        triangles=tris, leaf_of_triangle=leaf, leaf_area=np.full(n_leaves, side * side), optics=optics,
        sun_direction=sun, sky_radiance=sky,
    )


GREY = LeafOptics(0.3, 0.2, 0.5)


def single_leaf(normal, *, optics=GREY, sun=(0.3, -0.2, 0.9), sky=0.0, side=0.5):
    return ReferenceInputs(
        triangles=card([0.1, -0.2, 0.3], normal, side), leaf_of_triangle=np.array([0, 0]),
        leaf_area=np.array([side * side]), optics=optics, sun_direction=sun, sky_radiance=sky,
    )


def binomial_sigma(expected_count_fraction: float, n: int) -> float:
    """Relative σ of a count ~ Bin(n, p): sqrt((1 - p)/(n p))."""
    p = expected_count_fraction
    return math.sqrt((1.0 - p) / (n * p))


# --------------------------------------------------------------------------
# closed forms
# --------------------------------------------------------------------------


@pytest.mark.parametrize(
    "normal",
    [(0.3, -0.2, 0.9), (0.0, 0.0, 1.0), (1.0, 0.2, 0.0), (-0.3, 0.2, -0.9), (0.9, 0.1, -0.25)],
    ids=["facing", "tilted", "steep", "backlit", "grazing"],
)
def test_single_leaf_in_the_sun(normal):
    # Closed form (DESIGN.md section 3): an unshadowed leaf with unit normal n
    # under a sun s of irradiance 1 has E_direct = |n·s| (both faces summed,
    # one of them is lit), and nothing can scatter back onto it: E_scattered
    # is exactly 0. Beam source: E_direct counts sun photons hitting the leaf:
    # Bin(N, p) with p = A |n·s| / A_source, so σ_rel = sqrt((1-p)/(N p));
    # bound 4σ. Surface source (the default): every drawn point lies on the
    # leaf and sees the sun, so E_direct = N (A|n·s|/N) / A = |n·s| to rounding.
    inputs = single_leaf(normal)
    n_paths = 100_000
    cos = abs(float(np.dot(unit(normal), inputs.sun_direction)))
    beam = solve(inputs, ReferenceParams(paths=n_paths, seed=11, sun_sampling="beam"))
    p = inputs.leaf_area[0] * cos / beam.incident[0]
    sigma = cos * binomial_sigma(p, n_paths)
    assert np.all(np.abs(beam.e_direct[0] - cos) <= 4 * sigma), (beam.e_direct, cos, sigma)
    # every hit is a first hit of a sun photon
    assert beam.hits[0] == round(beam.e_direct[0, 0] * inputs.leaf_area[0] / (beam.incident[0] / n_paths))
    surface = solve(inputs, ReferenceParams(paths=n_paths, seed=11))
    np.testing.assert_allclose(surface.e_direct[0], cos, rtol=1e-9)
    assert surface.hits[0] == n_paths * ReferenceParams().split and surface.noise_rel_direct < 1e-9  # split first hits
    for res in (beam, surface):
        assert res.e_direct[0, 0] == res.e_direct[0, 1] == res.e_direct[0, 2]  # white sun, one photon set
        assert np.all(res.e_scattered == 0.0)
        assert np.all(res.e_sky == 0.0) and np.all(res.e_sky_scattered == 0.0)
        assert res.noise_rel == 0.0
        assert res.paths == n_paths and res.sky_paths == 0 and res.truncated == 0


@pytest.mark.parametrize("normal", [(0.0, 0.0, 1.0), (1.0, 0.0, 0.2), (0.2, 0.3, -0.8)])
def test_isolated_leaf_under_a_uniform_sky(normal):
    # A uniform sky of radiance L over the upper hemisphere gives an isolated
    # flat leaf, of any orientation, E = ∫_upper L |n·ω| dω = π L on its two
    # faces together (ω -> -ω maps the upper onto the lower hemisphere, and
    # the full sphere gives 2π L). Every sky photon carries the same power
    # w = incident / N, so the hit count is binomial: bound 4σ.
    sky = np.array([0.1, 0.2, 0.05])
    inputs = single_leaf(normal, sky=sky)
    n_sky = 200_000
    res = solve(inputs, ReferenceParams(paths=0, sky_paths=n_sky, seed=5))
    expected = math.pi * sky
    p = expected[0] * inputs.leaf_area[0] / res.incident[0]
    sigma = expected * binomial_sigma(p, n_sky)
    assert np.all(np.abs(res.e_sky[0] - expected) <= 4 * sigma), (res.e_sky, expected, sigma)
    assert np.all(res.e_direct == 0.0) and np.all(res.e_scattered == 0.0) and np.all(res.e_sky_scattered == 0.0)
    assert math.isnan(res.noise_rel)  # no sun paths, no E_scattered noise to report


def view_factor_parallel_squares(a: float, c: float) -> float:
    """Diffuse view factor between two directly opposed parallel a x a squares at distance c.

    Howell, *A Catalog of Radiation Heat Transfer Configuration Factors*, C-11
    (parallel, directly opposed rectangles); checked below against a midpoint
    quadrature of (1/A) ∫∫ cos θ1 cos θ2 / (π r²).
    """
    x = y = a / c
    return (2.0 / (math.pi * x * y)) * (
        math.log(math.sqrt((1 + x * x) * (1 + y * y) / (1 + x * x + y * y)))
        + x * math.sqrt(1 + y * y) * math.atan(x / math.sqrt(1 + y * y))
        + y * math.sqrt(1 + x * x) * math.atan(y / math.sqrt(1 + x * x))
        - x * math.atan(x)
        - y * math.atan(y)
    )


def test_view_factor_formula_against_quadrature():
    a, c, m = 1.0, 0.5, 24
    g = (np.arange(m) + 0.5) / m * a - a / 2
    x1, y1, x2, y2 = np.meshgrid(g, g, g, g, indexing="ij")
    r2 = (x1 - x2) ** 2 + (y1 - y2) ** 2 + c * c
    f = np.sum(c * c / (math.pi * r2 * r2)) * (a / m) ** 4 / (a * a)
    # midpoint rule error at m = 24 is ~1e-3 relative for this smooth kernel
    assert view_factor_parallel_squares(a, c) == pytest.approx(f, rel=2e-3)
    assert view_factor_parallel_squares(1.0, 1.0) == pytest.approx(0.19982, abs=1e-5)  # tabulated value


@pytest.mark.parametrize("gap", [0.02, 0.3])
def test_two_facing_leaves_transmitted_light(gap):
    # Leaf A (side a, normal +z) at height `gap` directly above leaf B, the sun
    # tilted by θ = 30° in the x-z plane. Leaves transmit (t per channel) and do
    # not reflect (r = 0), so:
    # * A is fully lit: E_direct(A) = cos θ, and nothing reaches it again
    #   (B sends its transmitted light downward): E_scattered(A) = 0 exactly.
    # * A's underside emits t cos θ uniformly, Lambertian, so B receives
    #   E_scattered(B) = t cos θ F with F the view factor between the squares
    #   (gap -> 0: F -> 1, E -> t cos θ, the brief's d << size limit).
    # * B is shaded except for a strip of width δ = gap tan θ:
    #   E_direct(B) = cos θ δ / a.
    # Each tally is a sum of equal-size Bernoulli contributions (sun photons
    # carry w0 each; after transmission at A the solver's weight is
    # w0 t_c / mean(t), see the module docstring), so σ_rel = sqrt((1-q)/(N q))
    # with q the probability per sun photon; bound 4σ.
    a = 1.0
    theta = math.radians(30.0)
    sun = np.array([math.sin(theta), 0.0, math.cos(theta)])
    t = np.array([0.1, 0.5, 0.9])
    optics = LeafOptics(0.0, t, 0.0)
    tris = np.concatenate([card([0, 0, gap], [0, 0, 1], a), card([0, 0, 0], [0, 0, 1], a)])
    inputs = ReferenceInputs(tris, np.array([0, 0, 1, 1]), np.array([a * a, a * a]), optics, sun)
    n_paths = 400_000
    res = solve(inputs, ReferenceParams(paths=n_paths, seed=3))
    cos = math.cos(theta)
    src = res.incident[0]
    f = view_factor_parallel_squares(a, gap)
    # A
    assert np.all(res.e_scattered[0] == 0.0)
    sig = cos * binomial_sigma(cos * a * a / src, n_paths)
    assert np.all(np.abs(res.e_direct[0] - cos) <= 4 * sig)
    # B, direct strip
    delta = gap * math.tan(theta)
    exp_direct_b = cos * delta / a
    sig = exp_direct_b * binomial_sigma(cos * delta * a / src, n_paths)
    assert np.all(np.abs(res.e_direct[1] - exp_direct_b) <= 4 * sig), (res.e_direct[1], exp_direct_b)
    # B, transmitted light from A
    expected = t * cos * f
    q = (cos * a * a / src) * t.mean() * f
    sig = expected * binomial_sigma(q, n_paths)
    assert np.all(np.abs(res.e_scattered[1] - expected) <= 4 * sig), (res.e_scattered[1], expected, sig)
    # with these numbers the bound is tight enough to matter: 4σ < 1.5 % of the value
    assert np.all(4 * sig < 0.015 * expected)


def test_energy_is_conserved_at_unit_albedo():
    """DESIGN.md section 4: energy conservation at albedo 1. Leaves with r + t = 1 per channel and
    white wood absorb nothing: all the power launched escapes (channel sums to rounding, each
    channel within the 4σ of test_energy_balance below), and no path is abandoned."""
    rng = np.random.default_rng(7)
    optics = LeafOptics((0.5, 0.7, 0.2), (0.5, 0.3, 0.8), 1.0)
    inputs = crown(150, rng, optics=optics, sky=0.1)
    n_sun, n_sky = 50_000, 20_000
    res = solve(inputs, ReferenceParams(paths=n_sun, sky_paths=n_sky, seed=2))
    assert np.all(res.absorbed == 0.0) and np.all(np.asarray(res.absorbed_wood) == 0.0)
    assert res.truncated == 0
    assert res.escaped.sum() == pytest.approx(res.incident.sum(), rel=1e-12)
    sky_power = solve(inputs, ReferenceParams(paths=0, sky_paths=2, seed=0)).incident
    w_sun = (res.incident - sky_power)[0] / n_sun
    sigma = np.sqrt(n_sun * (1.5 * w_sun) ** 2 + n_sky * (0.5 * sky_power.sum() / n_sky) ** 2)
    assert np.all(np.abs(res.escaped - res.incident) <= 4 * sigma), (res.escaped, res.incident, sigma)


def test_energy_balance():
    # Every launched photon's power ends absorbed (leaf or wood) or escaped.
    # The solver preserves each path's channel-summed weight exactly, so the
    # channel sums balance to rounding. Per channel the balance holds in
    # expectation: a sun path ends with channel-c power in [0, 3 w0] for w0
    # launched, a sky path in [0, S] for its channel sum S, so per path the
    # imbalance has variance <= (3 w0)²/4 resp. S²/4 (Popoviciu); bound 4σ.
    rng = np.random.default_rng(7)
    optics = LeafOptics((0.45, 0.2, 0.05), (0.45, 0.1, 0.3), (0.6, 0.3, 0.1))
    sky = np.array([0.05, 0.1, 0.2])
    inputs = crown(150, rng, optics=optics, sky=sky)
    n_sun, n_sky = 100_000, 50_000
    res = solve(inputs, ReferenceParams(paths=n_sun, sky_paths=n_sky, seed=2))
    out = res.absorbed.sum(axis=0) + res.absorbed_wood + res.escaped
    assert out.sum() == pytest.approx(res.incident.sum(), rel=1e-12)
    # sky power launched: the incident power of a sky-only run (same source)
    sky_power = solve(inputs, ReferenceParams(paths=0, sky_paths=2, seed=0)).incident
    w_sun = (res.incident - sky_power)[0] / n_sun
    s_sky = sky_power.sum() / n_sky
    sigma = np.sqrt(n_sun * (1.5 * w_sun) ** 2 + n_sky * (0.5 * s_sky) ** 2)
    assert np.all(np.abs(out - res.incident) <= 4 * sigma), (out, res.incident, sigma)
    assert np.all(np.abs(out - res.incident) <= 0.02 * res.incident)
    # a substantial share is absorbed, by leaves and by wood
    assert np.all(res.absorbed.sum(axis=0) > 0.02 * res.incident)
    assert np.all(res.absorbed_wood > 0)
    assert res.truncated == 0


# --------------------------------------------------------------------------
# noise and determinism
# --------------------------------------------------------------------------


def test_noise_falls_as_inverse_sqrt_of_paths():
    # noise_rel estimates the relative RMS error of E_scattered; MC error
    # scales as N^-1/2, so 4x the paths halves it. The ratio of two estimates
    # fluctuates: over 10 seed pairs it measured 0.513 ± 0.016 (slightly above
    # 0.5 because ‖a + b‖ in the denominator contains the noise too, which
    # matters at the ~22 % noise of the smaller run); tolerance 0.5 ± 0.08.
    rng = np.random.default_rng(1)
    inputs = crown(400, rng, side=0.12, optics=LeafOptics(0.45, 0.45, 0.3))
    r1 = solve(inputs, ReferenceParams(paths=60_000, seed=1, batch_size=1 << 13))
    r4 = solve(inputs, ReferenceParams(paths=240_000, seed=2, batch_size=1 << 13))
    assert 0.0 < r1.noise_rel < 1.0
    assert r4.noise_rel / r1.noise_rel == pytest.approx(0.5, abs=0.08)


def test_noise_estimate_predicts_the_difference_of_independent_runs():
    # Two independent full runs x1, x2 (different seeds) differ by
    # E‖x1 - x2‖² = 2 Σ Var(x), and ‖x1 + x2‖ ≈ 2‖x‖, so
    # √2 ‖x1 - x2‖ / ‖x1 + x2‖ estimates the same relative noise as each
    # run's two-halves noise_rel. A wrong factor (e.g. ‖a - b‖/‖a + b‖ without
    # the half-run normalisation, off by 2 or √2) fails. Over 10 seed pairs the
    # ratio measured 1.03 ± 0.05; tolerance ±25 %.
    rng = np.random.default_rng(4)
    inputs = crown(400, rng, side=0.12, optics=LeafOptics(0.45, 0.45, 0.3))
    p = {"paths": 80_000, "batch_size": 1 << 13}
    r1 = solve(inputs, ReferenceParams(seed=10, **p))
    r2 = solve(inputs, ReferenceParams(seed=20, **p))
    x1, x2 = r1.e_scattered, r2.e_scattered
    observed = math.sqrt(2) * np.linalg.norm(x1 - x2) / np.linalg.norm(x1 + x2)
    predicted = 0.5 * (r1.noise_rel + r2.noise_rel)
    assert observed / predicted == pytest.approx(1.0, abs=0.25)


def test_noise_estimates_of_direct_and_total_predict_the_difference_of_independent_runs():
    # As above, for E_direct (the surface source's stratified first hits) and the total. Over 6 seed
    # pairs the ratios measured 0.9-1.1; tolerance ±30 % (a wrong normalisation is off by √2 or 2).
    rng = np.random.default_rng(4)
    inputs = crown(400, rng, side=0.12, optics=LeafOptics(0.45, 0.45, 0.3))
    ratios_d, ratios_t = [], []
    for s in range(3):
        r1 = solve(inputs, ReferenceParams(paths=40_000, batch_size=1 << 12, seed=2 * s))
        r2 = solve(inputs, ReferenceParams(paths=40_000, batch_size=1 << 12, seed=2 * s + 1))
        for x1, x2, n1, n2, out in (
            (r1.e_direct, r2.e_direct, r1.noise_rel_direct, r2.noise_rel_direct, ratios_d),
            (r1.e_direct + r1.e_scattered, r2.e_direct + r2.e_scattered, r1.noise_rel_total, r2.noise_rel_total, ratios_t),
        ):
            out.append(math.sqrt(2) * np.linalg.norm(x1 - x2) / np.linalg.norm(x1 + x2) / (0.5 * (n1 + n2)))
    assert np.mean(ratios_d) == pytest.approx(1.0, abs=0.3), ratios_d
    assert np.mean(ratios_t) == pytest.approx(1.0, abs=0.3), ratios_t


def test_surface_source_and_expected_value_absorption_agree_with_the_analog_beam():
    # The default sampling (first hits drawn on the surfaces, absorption by expected value while a
    # photon is bright, splitting at the first hit) against the analog one this reference was
    # validated with (photons from a rectangle over the scene, absorption as the Russian roulette).
    # Both are unbiased estimates of the same tallies, so leaf by leaf their relative RMS difference
    # is sqrt(noise_a² + noise_b²) (each from its own two halves); a bias of a few % on top fails.
    # Bound 1.25x that (the noise estimates' own spread at ~1800 leaf-channel values is a few %).
    rng = np.random.default_rng(12)
    inputs = crown(200, rng, side=0.15, optics=LeafOptics((0.45, 0.2, 0.05), (0.4, 0.3, 0.1), 0.4))
    new = solve(inputs, ReferenceParams(paths=300_000, seed=1))
    old = solve(inputs, ReferenceParams(paths=300_000, seed=2, sun_sampling="beam", survival_weight=2.0))
    for name, noise in (("e_scattered", "noise_rel"), ("e_direct", "noise_rel_direct")):
        a, b = getattr(new, name), getattr(old, name)
        diff = np.linalg.norm(a - b) / np.linalg.norm(b)
        assert diff <= 1.25 * math.hypot(getattr(new, noise), getattr(old, noise)), (name, diff)
        # and the means agree within 4σ of the mean (σ of the per-leaf values / sqrt(leaves), at most)
        assert abs(a.mean() / b.mean() - 1) <= 4 * math.hypot(getattr(new, noise), getattr(old, noise)) / math.sqrt(a.shape[0])
    # the new sampling is the one worth having: at the same paths, its E_scattered noise is much lower
    assert new.noise_rel < 0.6 * old.noise_rel and new.noise_rel_direct < 0.8 * old.noise_rel_direct


def test_stops_at_a_noise_target_deterministically():
    rng = np.random.default_rng(13)
    inputs = crown(150, rng, optics=LeafOptics(0.3, 0.3, 0.2))
    params = ReferenceParams(paths=4_000_000, seed=3, batch_size=1 << 13, noise_target=0.05)
    a, b = solve(inputs, params), solve(inputs, params)
    assert a.noise_rel <= 0.05 < solve(inputs, ReferenceParams(paths=8 * (1 << 13), seed=3, batch_size=1 << 13)).noise_rel
    assert a.paths < 4_000_000 and a.paths % (2 * (1 << 13)) == 0  # an even number of whole batches
    np.testing.assert_array_equal(a.e_scattered, b.e_scattered)
    assert a.paths == b.paths
    # the same as a run of that many paths: stopping picks a prefix of the batches, nothing else
    fixed = solve(inputs, ReferenceParams(paths=a.paths, seed=3, batch_size=1 << 13))
    np.testing.assert_array_equal(a.e_scattered, fixed.e_scattered)
    np.testing.assert_array_equal(a.e_direct, fixed.e_direct)
    # an unreachable target traces every path and reports the noise it reached
    c = solve(inputs, ReferenceParams(paths=40_000, seed=3, batch_size=1 << 13, noise_target=1e-6))
    assert c.paths == 40_000 and c.noise_rel > 1e-6


def test_deterministic_for_a_seed_whatever_the_workers():
    rng = np.random.default_rng(9)
    inputs = crown(80, rng, optics=LeafOptics((0.4, 0.2, 0.1), (0.3, 0.2, 0.1), 0.3), sky=0.1)
    base = {"paths": 30_000, "sky_paths": 10_000, "batch_size": 4096}
    calls = []
    a = solve(inputs, ReferenceParams(seed=42, workers=2, **base), progress=lambda d, t: calls.append((d, t)))
    b = solve(inputs, ReferenceParams(seed=42, workers=2, **base))
    c = solve(inputs, ReferenceParams(seed=42, workers=1, **base))
    d = solve(inputs, ReferenceParams(seed=43, workers=2, **base))
    fields = ["e_direct", "e_scattered", "e_sky", "e_sky_scattered", "absorbed", "absorbed_wood"]
    fields += ["escaped", "incident", "hits"]
    for other in (b, c):
        for name in fields:
            np.testing.assert_array_equal(getattr(a, name), getattr(other, name), err_msg=name)
        assert a.noise_rel == other.noise_rel and a.noise_rel_total == other.noise_rel_total
    assert a.workers == 2 and c.workers == 1 and a.seed == 42
    assert not np.array_equal(a.e_scattered, d.e_scattered)
    # progress: once per batch (8 sun + 3 sky), increasing, ending at the total
    assert len(calls) == 8 + 3
    assert [t for _, t in calls] == [40_000] * len(calls)
    assert [d for d, _ in calls] == sorted(d for d, _ in calls) and calls[-1][0] == 40_000


# --------------------------------------------------------------------------
# an infinite layer against the exact plane-parallel solver
# --------------------------------------------------------------------------


def layer(lai: float, side: float, rng: np.random.Generator, optics: LeafOptics, sun, sky=0.0, cell=1.0):
    """A periodic cell x cell x 1 layer of randomly oriented cards, centres uniform in the cell."""
    n = round(lai * cell * cell / side**2)
    tris, centres = random_cards(n, side, rng, [0, 0, 0], [cell, cell, 1])
    inputs = ReferenceInputs(
        tris, np.repeat(np.arange(n), 2), np.full(n, side * side), optics, sun, sky_radiance=sky, period=(cell, cell)
    )
    # optical depth of each leaf's centre: G = 1/2 for uniform orientations
    return inputs, 0.5 * lai * (1.0 - centres[:, 2])


def bin_means(values: np.ndarray, depth: np.ndarray, edges: np.ndarray) -> np.ndarray:
    b = np.clip(np.digitize(depth, edges) - 1, 0, edges.size - 2)
    counts = np.bincount(b, minlength=edges.size - 1)
    sums = [np.bincount(b, weights=values[:, c], minlength=edges.size - 1) for c in range(values.shape[1])]
    return np.stack(sums, axis=1) / counts[:, None]


def test_periodic_layer_matches_plane_parallel_solver():
    # An infinite layer (LAI 2, 3200 cards of side 0.025 in a periodic 1 x 1 x 1
    # cell, uniform orientations) is the turbid medium of the discrete-ordinate
    # solver with tau = LAI/2 and the bi-Lambertian canopy phase function
    # (phase.py), in the limit of small leaves. For leaves of uniform
    # orientation the mean of E (both faces summed) is half the scalar
    # irradiance: E_scattered = actinic_flux_diffuse / 2 and
    # E_direct = (actinic_flux - actinic_flux_diffuse) / 2 = exp(-t/μ0)/2.
    # Compared: bin means over 8 depth bins (400 leaves each).
    # Tolerances: E_scattered 4 % per bin (measured ≤ 2.1 % for solver seeds
    # 3-6: MC spread ~0.5 % per bin, plus this one random leaf layout and the
    # finite leaf size); E_direct 8 % per bin (the unscattered beam sees the
    # gaps of this layout, which put bins up to 6.4 % off the turbid-medium mean
    # whatever the solver seed; MC spread ±0.5 %); absorptance 3 % (measured
    # ≤ 1.1 %). A reflect/transmit mix-up changes E_scattered by 30-80 % in
    # channels 0 and 2.
    from foliage_tools.lighting.phase import canopy_bilambertian_phase
    from foliage_tools.lighting.plane_parallel import solve_slab

    rng = np.random.default_rng(5)
    r = np.array([0.4, 0.45, 0.05])
    t = np.array([0.1, 0.45, 0.3])
    theta = math.radians(30.0)
    sun = (math.sin(theta), 0.0, math.cos(theta))
    lai = 2.0
    inputs, depth = layer(lai, 0.025, rng, LeafOptics(r, t, 0.0), sun)
    res = solve(inputs, ReferenceParams(paths=1_000_000, seed=3))
    assert res.truncated == 0
    mu0 = math.cos(theta)
    edges = np.linspace(0.0, 0.5 * lai, 9)
    exp_scat = np.empty((depth.size, 3))
    exp_dir = np.empty((depth.size, 3))
    for c in range(3):
        sol = solve_slab(
            tau=0.5 * lai, omega=r[c] + t[c], mu0=mu0,
            phase=canopy_bilambertian_phase(reflectance=r[c], transmittance=t[c]), depths=depth,
        )
        exp_scat[:, c] = sol.actinic_flux_diffuse / 2
        exp_dir[:, c] = (sol.actinic_flux - sol.actinic_flux_diffuse) / 2
        absorptance = res.absorbed[:, c].sum() / (mu0 * 1.0)  # per unit horizontal incident power
        assert absorptance == pytest.approx(sol.absorptance, rel=0.03)
    ratio_s = bin_means(res.e_scattered, depth, edges) / bin_means(exp_scat, depth, edges)
    ratio_d = bin_means(res.e_direct, depth, edges) / bin_means(exp_dir, depth, edges)
    assert np.all(np.abs(ratio_s - 1) < 0.04), ratio_s
    assert np.all(np.abs(ratio_d - 1) < 0.08), ratio_d


def test_periodic_layer_under_a_uniform_sky():
    # Same kind of layer, sky only (radiance L): unscattered sky light at
    # optical depth t has scalar irradiance 2π L E_2(t) (∫ over the downward
    # hemisphere of L exp(-t/μ)), so mean E_sky = π L E_2(t); all sky light
    # together is π L × (the solver's actinic flux for horizontal irradiance 1)
    # / 2. A 2 x 2 cell (3200 cards of side 0.05) keeps the spread between
    # random leaf layouts small: over 6 layouts the bin ratios were 1.00 ± 0.013
    # (E_sky) and 1.00 ± 0.008 (all sky light), no bias beyond 1 %; tolerances
    # 6 % and 4 % (about 4.5σ).
    from scipy.special import expn

    from foliage_tools.lighting.phase import canopy_bilambertian_phase
    from foliage_tools.lighting.plane_parallel import solve_slab_diffuse

    rng = np.random.default_rng(8)
    r, t = 0.3, 0.4
    sky = np.array([0.2, 0.1, 0.3])
    lai = 2.0
    inputs, depth = layer(lai, 0.05, rng, LeafOptics(r, t, 0.0), (0.0, 0.0, 1.0), sky=sky, cell=2.0)
    res = solve(inputs, ReferenceParams(paths=0, sky_paths=300_000, seed=4))
    assert res.truncated == 0 and np.all(res.e_direct == 0) and np.all(res.e_scattered == 0)
    sol = solve_slab_diffuse(
        tau=0.5 * lai, omega=r + t, phase=canopy_bilambertian_phase(reflectance=r, transmittance=t), depths=depth
    )
    edges = np.linspace(0.0, 0.5 * lai, 5)
    exp_sky = (math.pi * expn(2, depth))[:, None] * sky
    exp_all = (math.pi * sol.actinic_flux / 2)[:, None] * sky
    ratio_sky = bin_means(res.e_sky, depth, edges) / bin_means(exp_sky, depth, edges)
    ratio_all = bin_means(res.e_sky + res.e_sky_scattered, depth, edges) / bin_means(exp_all, depth, edges)
    assert np.all(np.abs(ratio_sky - 1) < 0.06), ratio_sky
    assert np.all(np.abs(ratio_all - 1) < 0.04), ratio_all


# --------------------------------------------------------------------------
# properties and input checks
# --------------------------------------------------------------------------


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    r=st.lists(st.floats(0.0, 0.6), min_size=3, max_size=3),
    t=st.lists(st.floats(0.0, 0.4), min_size=3, max_size=3),
    wood=st.floats(0.0, 1.0),
    sun=st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)).filter(lambda v: np.linalg.norm(v) > 0.1),
)
# found by hypothesis on a fresh clone (2026-12-03): a photon reflected by subnormal wood with black leaves in its
# only live channel underflows to zero weight, and the event draw then divided 0 by 0
@example(r=[0.0, 0.5, 0.5], t=[0.0, 0.0, 0.25], wood=5e-324, sun=(0.0, 1.0, 0.0))
def test_finite_nonnegative_and_balanced_for_any_optics_and_sun(r, t, wood, sun):
    rng = np.random.default_rng(0)
    inputs = crown(30, rng, optics=LeafOptics(r, t, wood), sun=sun, sky=0.05)
    res = solve(inputs, ReferenceParams(paths=4000, sky_paths=2000, seed=1, batch_size=1024))
    for name in ("e_direct", "e_scattered", "e_sky", "e_sky_scattered", "absorbed", "absorbed_wood", "escaped"):
        v = getattr(res, name)
        assert np.all(np.isfinite(v)) and np.all(v >= 0), name
    out = res.absorbed.sum(axis=0) + res.absorbed_wood + res.escaped
    assert out.sum() == pytest.approx(res.incident.sum(), rel=1e-12)
    if max(r) == 0 and max(t) == 0 and wood == 0:
        assert np.all(res.e_scattered == 0) and np.all(res.e_sky_scattered == 0)


def test_black_scene_scatters_nothing():
    rng = np.random.default_rng(3)
    res = solve(crown(50, rng, optics=BLACK), ReferenceParams(paths=20_000, seed=0))
    assert np.all(res.e_scattered == 0) and res.noise_rel == 0.0
    assert np.all(res.e_sky == 0) and res.e_direct.sum() > 0
    # black leaves and wood absorb everything they intercept
    assert res.absorbed.sum() + res.absorbed_wood.sum() > 0


def test_rejects_bad_input():
    tri = card([0, 0, 0], [0, 0, 1], 1.0)
    opt = LeafOptics(0.1, 0.1)
    with pytest.raises(ValueError, match="leaf index below L = 1"):
        ReferenceInputs(tri, np.array([0, 1]), np.array([1.0]), opt, (0, 0, 1))
    with pytest.raises(ValueError, match="leaf_area"):
        ReferenceInputs(tri, np.array([0, 0]), np.array([0.0]), opt, (0, 0, 1))
    with pytest.raises(ValueError, match="sun_direction"):
        ReferenceInputs(tri, np.array([0, 0]), np.array([1.0]), opt, (0, 0, 0))
    with pytest.raises(ValueError, match="sky_radiance"):
        ReferenceInputs(tri, np.array([0, 0]), np.array([1.0]), opt, (0, 0, 1), sky_radiance=-1)
    with pytest.raises(ValueError, match="up = \\(0, 0, 1\\)"):
        ReferenceInputs(tri, np.array([0, 0]), np.array([1.0]), opt, (0, 0, 1), up=(0, 1, 0), period=(1, 1))
    with pytest.raises(ValueError, match="above the horizon"):
        ReferenceInputs(tri, np.array([0, 0]), np.array([1.0]), opt, (0, 0, -1), period=(1, 1))
    with pytest.raises(ValueError, match="paths must be 0 or >= 2"):
        ReferenceParams(paths=1)
    with pytest.raises(ValueError, match="workers"):
        ReferenceParams(workers=0)
    inputs = ReferenceInputs(tri, np.array([0, 0]), np.array([1.0]), opt, (0, 0, 1), sky_radiance=0.1)
    with pytest.raises(ValueError, match="sky_paths"):
        solve(inputs, ReferenceParams(paths=10, sky_paths=0))
    with pytest.raises(ValueError, match="nothing to trace"):
        solve(ReferenceInputs(tri, np.array([0, 0]), np.array([1.0]), opt, (0, 0, 1)), ReferenceParams(paths=0))


def test_an_exception_in_progress_stops_the_run(monkeypatch):
    # Ctrl-C (or any error) raised from the progress callback must end the run
    # promptly: batches not yet started are cancelled. 20 M paths are 1221
    # batches; counted, not timed: only the window in flight when the first
    # batch reports (2 x workers + 1) may run.
    from foliage_tools.lighting import reference as ref_module

    rng = np.random.default_rng(2)
    inputs = crown(50, rng, optics=LeafOptics(0.1, 0.1, 0.1))
    ran = []
    run = ref_module._Tracer.run
    monkeypatch.setattr(ref_module._Tracer, "run", lambda self, *a: (ran.append(1), run(self, *a))[1])

    def stop(done, total):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        solve(inputs, ReferenceParams(paths=20_000_000, seed=0, batch_size=1 << 14, workers=2), progress=stop)
    assert 1 <= len(ran) <= 2 * 2 + 1


def _launch_weight(inputs: ReferenceInputs, res, n: int, sampling: str) -> float:
    """Power per sun path and channel: the beam rectangle's area / n, or Σ A|n·s| / n for the surface source."""
    if sampling == "beam":
        return float(res.incident[0]) / n
    tri = inputs.triangles
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    return float(np.sum(0.5 * np.abs(cross @ inputs.sun_direction))) / n


@pytest.mark.parametrize("sampling", ["surface", "beam"])
def test_mirror_symmetric_crown_under_a_zenith_sun_absorbs_alike_on_both_sides(sampling):
    """DESIGN.md section 4's symmetry check for the Monte Carlo reference.

    120 cards in a ball (x > 0 side) and their mirror images in x -> -x, a zenith
    sun: the two halves absorb the same power up to noise. Per sun path, the
    difference of the halves' absorbed channel-c power lies in [-3 w0, 3 w0]
    (w0 launched per path and channel), so its sum over n paths has σ <= sqrt(n) 3 w0
    (Popoviciu); bound 4σ. An x-sign error anywhere in the transport shows as a many-σ imbalance.
    """
    rng = np.random.default_rng(5)
    half = 120
    tris, centres = random_cards(half, 0.2, rng, [0.05, -0.8, -0.8], [0.8, 0.8, 0.8])
    flip = np.array([-1.0, 1.0, 1.0])
    mirrored = tris * flip
    tris_all = np.concatenate([tris, mirrored[:, ::-1]])  # reversed winding keeps the cards proper
    leaf = np.concatenate([np.repeat(np.arange(half), 2), np.repeat(np.arange(half, 2 * half), 2)])
    inputs = ReferenceInputs(triangles=tris_all, leaf_of_triangle=leaf, leaf_area=np.full(2 * half, 0.04),
                             optics=LeafOptics((0.45, 0.3, 0.1), (0.45, 0.2, 0.05)), sun_direction=(0.0, 0.0, 1.0))
    n = 200_000
    res = solve(inputs, ReferenceParams(paths=n, seed=4, sun_sampling=sampling, survival_weight=2.0 if sampling == "beam" else 0.1))
    w0 = _launch_weight(inputs, res, n, sampling)
    right, left = res.absorbed[:half].sum(axis=0), res.absorbed[half:].sum(axis=0)
    assert np.all(right > 0.05 * res.incident)  # the crown does absorb
    sigma = math.sqrt(n) * 3.0 * w0
    assert np.all(np.abs(right - left) <= 4 * sigma), (right, left, sigma)
    if sampling == "surface":
        # expected-value absorption spreads a path's deposit over many events, far inside Popoviciu's
        # bound: the demonstration below that the bound bites is the analog beam's
        return
    # and the bound can fail: the same crown under a low sun from +x (the x > 0 half shades the other) is many σ off
    tilted = ReferenceInputs(triangles=tris_all, leaf_of_triangle=leaf, leaf_area=np.full(2 * half, 0.04),
                             optics=inputs.optics, sun_direction=(math.cos(math.radians(30)), 0.0, math.sin(math.radians(30))))
    lit = solve(tilted, ReferenceParams(paths=n, seed=4, sun_sampling=sampling, survival_weight=2.0))
    w1 = _launch_weight(tilted, lit, n, sampling)
    assert np.all(lit.absorbed[:half].sum(axis=0) - lit.absorbed[half:].sum(axis=0) > 4 * math.sqrt(n) * 3.0 * w1)

@pytest.mark.slow
def test_the_issues_uniform_layer_made_periodic_matches_the_exact_solver():
    # The issue's layer (examples/make_layer.py: 10 x 10 x 1.5 m, 30 000 cards of 0.1 m, uniform
    # normals, LAI 3) as one cell of an infinite layer, r = t = 0.45, sun at elevation 60°: the
    # plane-parallel case of the exact solver (tau = 1.5, bi-Lambertian canopy phase). Per depth bin
    # (6000 leaves each) the mean E_scattered within 3 % (the issue's target; measured -1.1 ... +0.1 %
    # at 2M paths, bin noise ~0.3 %; the rest is this layout and the leaves' finite size).
    # The finite 10 x 10 layer is *not* this case: scattered light leaves through its sides, and its
    # inner region (|x|, |y| < 4 m) measured -4.7 ... -8.0 % against the same solver (|x|, |y| < 3 m:
    # -2.4 ... -4.6 %), the same code and layout, so that deficit is the layer's edges.
    import sys
    from pathlib import Path

    from foliage_tools.lighting.phase import canopy_bilambertian_phase
    from foliage_tools.lighting.plane_parallel import solve_slab

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "examples"))
    from make_layer import build_layer

    g = build_layer(seed=1)
    tri, ids = g.triangles()
    el = math.radians(60.0)
    sun = (math.cos(el), 0.0, math.sin(el))
    inputs = ReferenceInputs(tri, ids, np.full(g.leaf_count, 0.01), LeafOptics(0.45, 0.45), sun,
                             period=(10.0, 10.0), cell_origin=(-5.0, -5.0))
    res = solve(inputs, ReferenceParams(paths=2_000_000, seed=0))
    depth = np.clip(0.5 * 3.0 * (1.5 - g.centres[:, 2]) / 1.5, 0.0, 1.5)
    sol = solve_slab(tau=1.5, omega=0.9, mu0=sun[2], phase=canopy_bilambertian_phase(reflectance=0.45, transmittance=0.45),
                     depths=depth)
    ratio = bin_means(res.e_scattered, depth, np.linspace(0.0, 1.5, 6)) / bin_means(
        np.repeat(sol.actinic_flux_diffuse[:, None] / 2, 3, axis=1), depth, np.linspace(0.0, 1.5, 6))
    assert np.all(np.abs(ratio - 1) < 0.03), ratio
