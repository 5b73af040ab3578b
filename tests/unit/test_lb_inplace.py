"""The in-place pair of plain sweeps (the AA pattern, ``kernels_inplace``) against two push sweeps."""

from __future__ import annotations

import numpy as np
import pytest

from foliage_tools.lighting.collision import Medium
from foliage_tools.lighting.lb import LBParams, LBProblem, _Operator, base_boundary, solve, sun_boundary, sun_source
from foliage_tools.lighting.lb.layout import _BLOCK_VALUES


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


@pytest.mark.parametrize("storage", ["fp32", "fp16"])
@pytest.mark.parametrize("case", list(CASES))
def test_pair_in_place_is_two_push_sweeps(rng, case, storage):
    """Three pairs in place leave every slot (inflow slots included) bit for bit as six push sweeps do: the same
    collision arithmetic on the same values, the pair only moving them differently (module docstring of
    ``kernels_inplace``). Two materials, sparse occupancy, boundary inflow, beams (their first-collision source),
    several right-hand sides, blocks of several rows with a partial last one, and blocks of one row, so streaming
    crosses block edges and z-faces in every direction; the push sweep is tested against the float64 numpy step
    (``test_lb_solver``)."""
    shape, bounds, lattice = CASES[case]
    pb = _problem(rng, shape, bounds, lattice)
    op = _Operator(pb, "float32", storage)
    assert op.in_place
    if case.startswith("blocks"):
        assert op.NB > 1 and op.G == max(1, _BLOCK_VALUES // (op.nz * op.K))
    f = op.unscattered(pb)
    push, out = f.copy(), f.copy()
    for _ in range(3):
        for _ in range(2):
            op.sweep(push, out, residual=False)
            push, out = out, push
        op.sweep_pair(f)
    assert np.any(push != op.unscattered(pb))  # the sweeps moved the light
    np.testing.assert_array_equal(f, push)


def test_iterate_with_pairs_matches_push_only(rng):
    """Plain iteration runs its unmeasured sweeps in pairs in place: the solve's sweeps, residuals and field are those
    of push sweeps alone (forced here by treating the layout as not in place)."""
    pb = _problem(rng, (8, 9, 10), (sun_source((0.3, -0.2, -0.9)), sun_boundary((0.1, 0.2, 0.97))))
    params = LBParams(tolerance=1e-6, solver="iterate", check_every=5)
    paired = solve(pb, params)

    orig = _Operator.in_place
    try:
        _Operator.in_place = property(lambda self: False)  # type: ignore[method-assign]
        pushed = solve(pb, params)
    finally:
        _Operator.in_place = orig  # type: ignore[method-assign]
    assert paired.iterations == pushed.iterations and paired.converged
    np.testing.assert_array_equal(paired.energy_density, pushed.energy_density)
    assert paired.history == pushed.history
