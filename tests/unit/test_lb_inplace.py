"""The in-place pair of plain sweeps (the AA pattern, ``kernels_inplace``) against two push sweeps, and the
collision by symmetry blocks it uses (``kernels_collide._collide_sym``) against the parity-split products."""

from __future__ import annotations

import numpy as np
import pytest

from foliage_tools.lighting.lb.collision import Medium, brown, unit_moving_block
from foliage_tools.lighting.lb import LBParams, LBProblem, _Operator, base_boundary, solve, sun_boundary, sun_source
from foliage_tools.lighting.lb.kernels_collide import (
    _EVEN_SLOTS,
    _ODD_SLOTS,
    SYM_RUN,
    _collide_pairs,
    _collide_run,
    _parity_blocks,
    _symmetry_bases,
    _symmetry_blocks,
)
from foliage_tools.lighting.lb.layout import _BLOCK_VALUES
from foliage_tools.lighting.lb.storage import from_storage


def _problem(rng, shape, bounds, lattice="ordinates"):
    rho = rng.uniform(0.05, 0.9, shape)
    rho[rng.uniform(size=shape) < 0.3] = 0.0
    med = Medium(sigma_a=(0.1, 0.3, 0.02), sigma_s=(0.85, 0.6, 0.97), g=(0.4, -0.7, 0.0))
    return LBProblem(rho, med, bounds, brown_mask=rng.uniform(size=shape) < 0.2, lattice=lattice)


CASES = {
    # (shape, boundaries, lattice): G rows per block and NB blocks follow from nz K (``_BLOCK_VALUES``)
    "one-block-sun": ((9, 7, 5), (sun_boundary((0.3, 0.2, 0.9)),), "ordinates"),
    "one-block-beam+bases": ((6, 11, 4), (sun_source((0.3, -0.2, -0.9)), base_boundary(7), base_boundary(0)), "ordinates"),
    "blocks-last-partial-beam": ((5, 23, 300), (sun_source((-0.6, 0.5, 0.62)),), "ordinates"),
    "blocks-of-one-row": ((4, 9, 700), (sun_boundary((0.3, 0.2, 0.9)),), "ordinates"),
    "geist2008": ((7, 8, 6), (sun_boundary((-0.3, 0.7, -0.6)), base_boundary(3)), "geist2008"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_pair_in_place_is_two_push_sweeps(rng, case):
    """Three pairs in place leave the field as six push sweeps do, to float32 rounding, and the inflow
    slots exactly at b. Two materials, sparse occupancy, boundary inflow, beams (their first-collision source),
    several right-hand sides, blocks of several rows with a partial last one, and blocks of one row, so streaming
    crosses block edges and z-faces in every direction; the push sweep is tested against the float64 numpy step
    (``test_lb_solver``). The pair collides by the symmetry blocks, the push sweep by the (9 x 9) products: each
    sweep's sums of <= 19 terms differ by ~1e-7 of the largest value in float32, and the sweep does not amplify
    differences (its column sums are <= 1), so six sweeps stay within 2e-6 of it. fp32 storage only: with fp16
    plain iteration keeps push sweeps (``_Operator.in_place``), so the pair is never run on it."""
    shape, bounds, lattice = CASES[case]
    pb = _problem(rng, shape, bounds, lattice)
    op = _Operator(pb, "float32")
    assert op.in_place and not _Operator(pb, "float32", "fp16").in_place
    if case.startswith("blocks"):
        assert op.NB > 1 and op.G == max(1, _BLOCK_VALUES // (op.nz * op.K))
    f = op.unscattered(pb)
    push, out = f.copy(), f.copy()
    for _ in range(3):
        for _ in range(2):
            op.sweep(push, out, residual=False)
            push, out = out, push
        op.sweep_pair(f)
    a, b = from_storage(f), from_storage(push)
    assert np.any(b != from_storage(op.unscattered(pb)))  # the sweeps moved the light
    assert (a >= 0).all()
    np.testing.assert_allclose(a, b, rtol=0, atol=2e-6 * np.abs(b).max())
    inflow = np.moveaxis(op._padded(op.inflow_mask), -1, 3)  # (nx, NB, G, 18, nz)
    nodes_a, nodes_b = op._nodes(f), op._nodes(push)  # (nx, NB, G, 18, C, nz, K)
    np.testing.assert_array_equal(np.moveaxis(nodes_a, 4, -1)[inflow], np.moveaxis(nodes_b, 4, -1)[inflow])


@pytest.mark.parametrize("lattice", ["ordinates", "geist2008"])
def test_symmetry_blocks_are_the_collision(rng, lattice):
    """The 30 symmetry-block coefficients rebuild the parity blocks exactly (A = W^T N W, ``_symmetry_blocks``),
    and the fused collision ``_collide_run`` gives the products' E and O (``_collide_pairs``) to float32 rounding,
    with two materials and the beams' source; a block without the cubic symmetry is refused."""
    med = Medium(sigma_a=(0.1, 0.3, 0.02), sigma_s=(0.85, 0.6, 0.97), g=(0.4, -0.7, 0.0))
    A = np.stack([unit_moving_block(m, lattice) for m in (med, brown(med))])
    AE, AO = _parity_blocks(A)
    Q = _symmetry_blocks(AE, AO)
    W_even, W_odd = _symmetry_bases()
    for W, M, (lo, slots) in ((W_even, AE, (0, _EVEN_SLOTS)), (W_odd, AO, (15, _ODD_SLOTS))):
        N = np.zeros(M.shape)
        for k, (i, j) in enumerate(slots):
            N[..., i, j] = Q[..., lo + k]
        np.testing.assert_allclose(np.einsum("ip,...ij,jq->...pq", W, N, W), M, rtol=0, atol=1e-14)
    n = 1000
    F = rng.uniform(0, 1, (18, 3, n)).astype(np.float32)
    own = rng.uniform(size=n) < 0.3
    rho = rng.uniform(0, 1, n)
    rexp = np.zeros((2, 2, n), np.float32)
    rexp[0] = np.where(own, 0.0, [rho, 0.9 * rho])
    rexp[1] = np.where(own, [rho, 0.9 * rho], 0.0)
    has = np.ones(2, bool)
    pexp = rng.uniform(0, 1, (2, 3, n)).astype(np.float32)
    cE, cO = (rng.uniform(0, 0.1, (2, 3, 9, 1)).astype(np.float32) for _ in range(2))
    EO = np.empty(36 * SYM_RUN, np.float32)
    _collide_run(F, 1, 0, n, rexp, 0, has, Q.astype(np.float32), EO, pexp, 0, cE, cO, True, True)
    E, O = (np.empty((9, n), np.float32) for _ in range(2))
    scratch = [np.empty((9, 9), np.float32), np.empty((9, 9), np.float32), np.empty((9, n), np.float32),
               np.empty((9, n), np.float32)]
    _collide_pairs(F, 1, 0, n, rexp, 0, has, AE.astype(np.float32), AO.astype(np.float32), *scratch, E, O,  # type: ignore[call-arg]
                   np.empty(18 * n, np.float32), pexp, 0, cE, cO, True, True)
    got = EO.reshape(36, SYM_RUN)[:18, :n]
    np.testing.assert_allclose(got, np.concatenate([E, O]), rtol=0, atol=1e-6 * np.abs(E).max())
    bad = A.copy()
    bad[0, :, 6, 0] += 0.05  # breaks the cubic symmetry (keeps the inversion symmetry the parity split needs)
    bad[0, :, 7, 1] += 0.05
    with pytest.raises(ValueError, match="cubic symmetry"):
        _symmetry_blocks(*_parity_blocks(bad))


def test_iterate_with_pairs_matches_push_only(rng):
    """Plain iteration runs its unmeasured sweeps in pairs in place: the solve takes the sweeps push sweeps alone take
    (forced here by treating the layout as not in place), and its field agrees with theirs to 1e-4, its residuals
    to 1e-4 or 1e-7. Why: both stop with a residual below the tolerance 1e-6 and are then within ~ residual / (1 - q)
    of the same fixed point (q <= 0.99 here); the pairs' rounding (test above) differs by ~1e-7 of the field per
    sweep, which is what a relative residual (the rms change per sweep) can differ by."""
    pb = _problem(rng, (8, 9, 10), (sun_source((0.3, -0.2, -0.9)), sun_boundary((0.1, 0.2, 0.97))))
    params = LBParams(tolerance=1e-6, solver="iterate", check_every=5)
    paired = solve(pb, params)

    orig = _Operator.in_place
    try:
        _Operator.in_place = property(lambda self: False)  # type: ignore[method-assign, assignment]
        pushed = solve(pb, params)
    finally:
        _Operator.in_place = orig  # type: ignore[method-assign]
    assert paired.iterations == pushed.iterations and paired.converged
    np.testing.assert_allclose(paired.energy_density, pushed.energy_density, rtol=1e-4)
    np.testing.assert_allclose(paired.history, pushed.history, rtol=1e-4, atol=1e-7)


def test_pairs_leave_the_round_off_floor_to_the_push_sweeps(rng):
    """Near float32's round-off floor the pairs' other arithmetic would set where the residual stalls (this problem:
    at 5.2e-8 with pairs to the end, against 3.0e-8 with push sweeps alone; tree_small at 48^3 likewise): plain
    iteration stops pairing below ``PAIR_MIN_RESIDUAL_EPS`` eps, and reaches the tolerance 3e-8 push sweeps reach."""
    from foliage_tools.lighting.lb.collision import leaf_medium

    rho = np.zeros((40, 40, 40))
    occupied = rng.uniform(size=rho.shape) < 0.15
    rho[occupied] = rng.uniform(0.05, 0.5, occupied.sum())
    pb = LBProblem(rho, leaf_medium(), (sun_source((0.3, -0.2, -0.9)),))
    paired = solve(pb, LBParams(tolerance=3e-8, solver="iterate"))
    assert paired.converged and paired.residual < 3e-8, (paired.residual, paired.iterations)
