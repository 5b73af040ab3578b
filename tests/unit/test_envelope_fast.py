"""The fast path's parts (foliage_tools.lighting.envelope) against direct sums.

Each part is checked against the sum it replaces, on inputs small enough to
sum directly: the pruned FFTs against scipy's full transforms, the FFT
far field against the correlation over grid nodes it stands for, the
half-pair near field against the sum over all ordered pairs.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.fft

from foliage_tools.lighting import envelope as env
from tests.helpers.crowns import uniform_ball


def test_pruned_transforms_match_scipy():
    """Skipping the zero padding (forward) and the cropped rows (inverse) changes nothing.

    float32 transforms: agreement to 1e-5 of the largest value (round-off ~1e-7 per pass).
    """
    rng = np.random.default_rng(0)
    grid = rng.uniform(size=(2, 5, 7, 6)).astype(np.float32)
    pad = (10, 14, 12)
    full = scipy.fft.rfftn(grid, s=pad, axes=(1, 2, 3))
    pruned = env._rfftn_padded(grid, pad)
    assert pruned.shape == full.shape
    np.testing.assert_allclose(pruned, full, atol=1e-5 * np.abs(full).max())
    spec = scipy.fft.rfftn(rng.uniform(size=(3,) + pad).astype(np.float32), axes=(1, 2, 3))
    back = scipy.fft.irfftn(spec, s=pad, axes=(1, 2, 3))[:, :5, :7, :6]
    cropped = env._irfftn_cropped(spec, pad, (5, 7, 6))
    assert cropped.shape == back.shape
    np.testing.assert_allclose(cropped, back, atol=1e-5 * np.abs(back).max())


def _node_kernel(v, band, power):
    """Octant-0 weight of the far kernel at integer offsets v (node units, h = 1); see _far_kernel_spectra.

    band = (r_a, r_b, r_c, r_d): 0 below r_a, smoothstep up to 1 at r_b, down to 0 from r_c to r_d.
    """
    r = math.sqrt(float(v @ v))
    r_a, r_b, r_c, r_d = band
    if r <= r_a:
        return 0.0
    t = min(max((r_b - r) / (r_b - r_a), 0.0), 1.0)
    w = 1.0 - t * t * (3.0 - 2.0 * t)
    if math.isfinite(r_c):
        t = min(max((r_d - r) / (r_d - r_c), 0.0), 1.0)
        w *= t * t * (3.0 - 2.0 * t)
    return w / (env.BIN_SOLID_ANGLE * r**power)


def _membership(v, j):
    """Share of octant j at offset v: 1 inside, 0 outside, 1/2 per zero component (node on a bin plane)."""
    signs = (1 if j & 1 else -1, 1 if j & 4 else -1, 1 if j & 2 else -1)  # x, y, z of octant j
    share = 1.0
    for a in range(3):
        if v[a] == 0:
            share *= 0.5
        elif np.sign(v[a]) != signs[a]:
            return 0.0
    return share


def test_far_field_is_the_node_correlation():
    """Leaves on grid nodes: the FFT far field equals Σ_q K_j(q - P) m_q(v^) summed directly over the leaves.

    On a node the cloud-in-cell deposit and read-back are exact, so the only
    difference is float32 FFT round-off (tolerance 1e-4 of the largest sum).
    This pins the kernels (constant and the three |v_k|/r ones of the fit,
    m = a + β·|v^|; the constant alone for a mass without direction), their
    reflections to the 8 octants (j and 7 - j share a mass), the spectra of
    octant 7 - j as conjugates of octant j's, and the FFT sizes of a band
    that ends within the grid (s + reach instead of 2 s - 1: what wraps
    around must fall into the zero padding).
    """
    rng = np.random.default_rng(4)
    shape = (9, 7, 8)
    nodes = np.array(np.meshgrid(*[np.arange(s) for s in shape], indexing="ij")).reshape(3, -1).T
    x = nodes[rng.choice(len(nodes), size=80, replace=False)].astype(np.float64)
    x += 1e-12  # floor() of exact integers must not fall to the node below through round-off
    fit = rng.uniform(0.5, 1.0, size=(80, 4, 4))
    fit[:, :, 1:] -= 0.75  # β of either sign, as fits give
    mean = rng.uniform(0.5, 1.0, size=(80, 4, 1))
    whole = (1.5, 2.5, math.inf, math.inf)
    band = (1.5, 2.5, 3.0, 4.5)  # reaches 5 nodes: FFT sizes (14, 12, 13) -> 15, 12, 15
    assert env._grid_pad(shape, band) < env._grid_pad(shape, whole)
    cases = []
    for mass in (fit, mean):
        got = env._far_field(x, mass, np.zeros(3), 1.0, shape, [(whole, 2), (whole, 1)])
        cases += [(got[0], mass, whole, 2), (got[1], mass, whole, 1)]
        (got,) = env._far_field(x, mass, np.zeros(3), 1.0, shape, [(band, 2)])
        cases.append((got, mass, band, 2))
    for got, mass, kband, power in cases:
        want = np.zeros_like(got)
        for p in range(len(x)):
            for q in range(len(x)):
                if q == p:
                    continue
                v = np.rint(x[q] - x[p]).astype(int)
                k = _node_kernel(v, kband, power)
                if k == 0.0:
                    continue
                for j in range(8):
                    m = mass[q, min(j, 7 - j)]
                    mq = m[0] + (m[1:] @ np.abs(v) / math.sqrt(float(v @ v)) if len(m) == 4 else 0.0)
                    want[p, j] += mq * _membership(v, j) * k
        assert np.count_nonzero(want) > 0.3 * want.size
        np.testing.assert_allclose(got, want, atol=1e-4 * np.abs(want).max())


def test_far_field_removes_a_leafs_own_mass():
    """A lone leaf off the nodes: its own deposit, read back through its cell's nodes, is removed exactly.

    Only the cell diagonals (|v_k|/r = 1/√3, see _interpolate) carry kernel
    weight within a cell when r_1 >= √2 h, so the far field of a lone leaf is
    0 up to float32 round-off, for any fit (a, β). The self term itself is
    checked to be large: without the β part of the removal the residual would
    be ~0.4 of it.
    """
    rng = np.random.default_rng(5)
    shape = (6, 6, 6)
    h, r1, r2 = 1.0, 1.5, 2.0
    for _ in range(5):
        x = rng.uniform(2.1, 2.9, size=(1, 3))
        mass = np.empty((1, 4, 4))
        mass[0, :, 0] = rng.uniform(0.1, 0.3, size=4)
        mass[0, :, 1:] = rng.uniform(0.5, 1.0, size=(4, 3))
        depth, s1 = env._far_field(x, mass, np.zeros(3), h, shape, [((r1, r2, math.inf, math.inf), p) for p in (2, 1)])
        f = x[0] - np.floor(x[0])
        self_term = np.prod(f * (1.0 - f)) / (env.BIN_SOLID_ANGLE * 3.0) * (mass[0, :, 0] + mass[0, :, 1:].sum(axis=1) / math.sqrt(3.0))
        assert self_term.min() > 1e-4
        np.testing.assert_allclose(depth, 0.0, atol=1e-5 * self_term.max())
        np.testing.assert_allclose(s1, 0.0, atol=1e-5 * self_term.max() * math.sqrt(3.0))


def test_octant_projection_fit():
    """The linear fit of A |N·d| over each octant pair (_octant_projection).

    Where N·d keeps one sign over octant j the projection is linear in |d_k|
    and the fit is exact: a = 0, β = A |N| componentwise. Elsewhere the fit's
    mean over the octant equals the mean of A |N·d| (least squares with a
    constant term), checked against a fine midpoint rule in (μ, φ): within
    2% (the fit's 4 x 4 Gauss rule integrates the kink of |N·d| to 1.4% on
    these normals; a wrong sign pattern of an octant is off by tens of %).
    """
    n = np.array([[0.3, -0.5, 0.81], [0.9, 0.2, -0.1], [0.0, 1.0, 0.0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    area = np.array([2.0, 0.5, 1.0])
    fit = env._octant_projection(n, area)
    assert fit.shape == (3, 4, 4)
    # leaf 0: octant pair 3 is x > 0, y < 0, z > 0, where N·d = 0.3 |d_x| + 0.5 |d_y| + 0.81 |d_z| > 0
    np.testing.assert_allclose(fit[0, 3], [0.0, *(area[0] * np.abs(n[0]))], atol=1e-12)
    # leaf 2 (N = y): |N·d| = |d_y| on every octant
    for j in range(4):
        np.testing.assert_allclose(fit[2, j], [0.0, 0.0, 1.0, 0.0], atol=1e-12)
    # means over the octant against a 400 x 400 midpoint rule (uniform in solid angle: μ = |d_y|, φ)
    k = (np.arange(400) + 0.5) / 400
    mu, ph = np.meshgrid(k, 0.5 * math.pi * k, indexing="ij")
    s = np.sqrt(1.0 - mu * mu)
    e = np.stack([s * np.cos(ph), mu, s * np.sin(ph)], axis=-1).reshape(-1, 3)
    for j in range(4):
        sign = np.array([1.0 if j & 1 else -1.0, -1.0, 1.0 if j & 2 else -1.0])
        for i in range(3):
            exact = area[i] * np.mean(np.abs((e * sign) @ n[i]))
            fitted = np.mean(fit[i, j, 0] + e @ fit[i, j, 1:])
            assert abs(fitted - exact) <= 0.02 * exact
    # and the fit is closer to A |N·d| than the octant mean (what the far field used before)
    sign = np.array([-1.0, -1.0, -1.0])
    f = area[1] * np.abs((e * sign) @ n[1])
    resid_fit = np.sqrt(np.mean((fit[1, 0, 0] + e @ fit[1, 0, 1:] - f) ** 2))
    resid_mean = np.sqrt(np.mean((f - f.mean()) ** 2))
    assert resid_fit < 0.5 * resid_mean


def test_near_sums_match_all_ordered_pairs():
    """The half-pair near field (each pair once, added to both leaves) equals the sum over all ordered pairs.

    Direct form: for every P and every other leaf q within r_2, o = min(A_q |N_q·d|/(Ω r³), max_occlusion),
    w = smoothstep from 1 at r_1 to 0 at r_2, D += w -ln(1 - o), S1 += w o r in P's octant of d = q - P.
    Includes an exact duplicate (no direction: skipped) and a touching pair (o clamped).
    Differences: summation order and the Taylor series of -ln(1 - o) below o = 0.05
    (relative error < o⁶/7 < 3e-9, see _neg_log1m): rtol 1e-8.
    """
    rng = np.random.default_rng(7)
    n = 400
    x = rng.uniform(-1.0, 1.0, size=(n, 3))
    x[1] = x[0]  # duplicate
    x[3] = x[2] + 1e-4  # touching: o far above max_occlusion
    # exact ties of a coordinate (coplanar or mirrored leaves of real assets): a zero component
    # counts as not positive from both ends, so the two leaves' octants are not opposite (7 - b)
    x[5] = x[4] + [0.05, 0.0, 0.0]
    x[7] = x[6] + [0.0, 0.0, -0.04]
    x[10:40, 1] = 0.3  # thirty leaves at one height
    nl = rng.normal(size=(n, 3))
    nl /= np.linalg.norm(nl, axis=1, keepdims=True)
    area = rng.uniform(0.001, 0.004, size=n)
    r1, r2, max_occ = 0.2, 0.35, 0.99
    depth, s1, pairs = env._near_sums(x, nl, area, x.min(axis=0), r1, r2, max_occ)

    d = x[None, :, :] - x[:, None, :]  # d[p, q] = q - P
    r = np.linalg.norm(d, axis=2)
    use = (r > 0.0) & (r < r2)
    rs = np.where(use, r, 1.0)
    o = np.minimum(area[None, :] * np.abs(np.einsum("pqk,qk->pq", d, nl)) / (rs**3 * env.BIN_SOLID_ANGLE), max_occ)
    t = np.clip((r2 - r) / (r2 - r1), 0.0, 1.0)
    w = np.where(use, t * t * (3.0 - 2.0 * t), 0.0)
    octant = (d[..., 0] > 0) + 2 * (d[..., 2] > 0) + 4 * (d[..., 1] > 0)
    want_d = np.zeros((n, 8))
    want_s = np.zeros((n, 8))
    for b in range(8):
        sel = use & (octant == b)
        want_d[:, b] = np.sum(np.where(sel, w * -np.log1p(-o), 0.0), axis=1)
        want_s[:, b] = np.sum(np.where(sel, w * o * r, 0.0), axis=1)
    assert pairs == int(np.count_nonzero(use))
    assert o[2, 3] == max_occ and not use[0, 1]
    np.testing.assert_allclose(depth, want_d, rtol=1e-8, atol=1e-14)
    np.testing.assert_allclose(s1, want_s, rtol=1e-8, atol=1e-14)


def test_fast_path_depth_error_at_40k_leaves():
    """40k leaves of a uniform ball (τ R = 2): the fast path's optical depth τ s_max against the exact sum.

    The exact per-bin depths of 500 random leaves (all 40k partners each, the
    reference path's sum) against the fast path's, over bins deeper than
    0.05 R, measured over crown seeds 1-5 with the defaults (near field to
    r_2 = 4.3 h): with the fine grid a median relative error of 0.43-0.46%
    and a 95th percentile of 1.66-1.82% (seed 2: 0.45%, 1.70%); on the single
    grid of step h 0.52-0.55% and 2.97-3.38% (seed 2: 0.53%, 3.26%). Bounds
    0.5% / 1.9% and 0.6% / 3.5%. The near field to r_2 = 2.5 h fails them
    (seed 2: 0.70%, 3.45% with the fine grid, 1.00%, 5.33% without), and so
    does the default without its fine grid (against the first pair).
    The depth is what the lighting uses and does not depend on τ's split.
    """
    c, n, a = uniform_ball(40000, tau=2.0, seed=2)  # A = 2 τ / ρ, eq. (5.5)
    frame = env.sample_frame((0, 0, 1))
    x, nl = np.ascontiguousarray(c @ frame.T), np.ascontiguousarray(n @ frame.T)
    probes = np.sort(np.random.default_rng(0).choice(len(c), 500, replace=False)).astype(np.int64)
    depth, far, s1 = env._reference_depths(x, nl, a, probes, env.EnvelopeParams().max_occlusion)
    tau = env._estimate_tau(depth, far, s1, "moments")
    deep = depth / tau >= 0.05
    for fine, med_max, p95_max in ((True, 0.005, 0.019), (False, 0.006, 0.035)):
        fast = env.solve(c, n, a, params=env.EnvelopeParams(path="fast", fast_fine_grid=fine))
        assert fast.path == "fast"
        assert ("fine_grid" in fast.stats) == fine
        got = fast.tau * fast.smax[probes].astype(float)
        rel = np.abs(got[deep] - depth[deep]) / depth[deep]
        assert np.median(rel) <= med_max
        assert np.percentile(rel, 95) <= p95_max


def test_fine_grid_falls_back_to_one_grid_under_the_cell_cap():
    """When ``fast_max_cells`` leaves the fine grid less than 4/3 finer than the coarse one, one grid is used.

    The fallback is the single-grid computation itself (same sums, bit for
    bit); without the cap the fine grid is used and changes the depths.
    """
    c, n, a = uniform_ball(3000, tau=2.0, seed=3)
    capped = env.solve(c, n, a, params=env.EnvelopeParams(path="fast", fast_max_cells=18))
    single = env.solve(c, n, a, params=env.EnvelopeParams(path="fast", fast_max_cells=18, fast_fine_grid=False))
    fine = env.solve(c, n, a, params=env.EnvelopeParams(path="fast"))
    assert "fine_grid" not in capped.stats and "fine_grid" in fine.stats
    assert max(fine.stats["fine_grid"]) > 1.5 * max(fine.stats["grid"])
    np.testing.assert_array_equal(capped.smax, single.smax)
    assert np.all(np.isfinite(fine.smax)) and np.all(fine.smax >= 0.0)
    assert np.abs(fine.smax - single.smax).max() > 1e-3 * fine.smax.max()


def test_fine_grid_parameters_are_checked():
    for bad in (
        {"fast_fine_ratio": 0.8},
        {"fast_fine_ratio": 0.0},
        {"fast_mid_start_cells": 2.5},
        {"fast_mid_start_cells": 8.0, "fast_mid_end_cells": 8.0},
        {"fast_mid_end_cells": math.inf},
    ):
        try:
            env.EnvelopeParams(**bad)
        except ValueError:
            continue
        raise AssertionError(f"EnvelopeParams accepted {bad}")
