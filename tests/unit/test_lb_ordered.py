"""``solver="ordered"``: in-place sweeps in alternating lexicographic order reach the plain iteration's fixed point."""

from __future__ import annotations

import numpy as np
import pytest

from foliage_tools.lighting.collision import Medium, brown
from foliage_tools.lighting.lb import LBParams, LBProblem, relighting_boundaries, solve, sun_boundary, sun_source


def _problem(kind: str) -> LBProblem:
    rng = np.random.default_rng(3)
    shape = (11, 9, 13)
    rho = np.where(rng.uniform(size=shape) < 0.35, rng.uniform(0.05, 0.6, shape), 0.0)
    med = Medium(sigma_a=(0.1, 0.05, 0.3), sigma_s=(0.9, 0.95, 0.7), g=(0.2, 0.0, -0.1))
    mask = rng.uniform(size=shape) < 0.15
    if kind == "bases":
        bounds = tuple(relighting_boundaries()[1:])
    elif kind == "beam":
        bounds = (sun_source((0.2, -0.5, 0.8)),)
    else:
        bounds = (sun_boundary((0.2, -0.5, 0.8)),)
    return LBProblem(rho, med, bounds, brown_mask=mask, brown_medium=brown(med))


@pytest.mark.parametrize("kind", ["bases", "beam", "sun"])
@pytest.mark.parametrize("storage", ["fp32", "fp16"])
def test_ordered_reaches_the_plain_fixed_point(kind, storage):
    """Two materials, boundary inflow and a first-collision beam: ordered sweeps stop on the same test as plain
    iteration (a plain sweep's residual below the tolerance) in fewer sweeps, and are as close to a float64
    solve as plain iteration is at that tolerance. The factor 2: both stop somewhere below the tolerance (plain
    iteration checks every 4 sweeps, ordered every 2), so their distances from the fixed point differ by the
    ratio of their last residuals; a wrong operator (another fixed point) is off by orders of magnitude more.
    fp16 at 1e-5 is at its rounded fixed point (lighting.storage), where both read the same."""
    pb = _problem(kind)
    tol = 1e-6 if storage == "fp32" else 1e-5
    tight = solve(pb, LBParams(tolerance=1e-9, solver="iterate", dtype="float64"))
    ordered = solve(pb, LBParams(tolerance=tol, solver="ordered", storage=storage))
    plain = solve(pb, LBParams(tolerance=tol, solver="iterate", storage=storage))
    assert ordered.converged and ordered.solver == "ordered" and ordered.residual < tol
    assert ordered.iterations < plain.iterations
    scale = float(tight.energy_density.max())
    err_ordered = np.abs(ordered.energy_density - tight.energy_density).max() / scale
    err_plain = np.abs(plain.energy_density - tight.energy_density).max() / scale
    assert err_ordered <= 2 * err_plain, (err_ordered, err_plain)


def test_ordered_with_no_room_to_measure_still_reports_a_residual():
    """max_sweeps 1: one ordered sweep leaves no sweep to measure it with; a plain one is added, never inf."""
    r = solve(_problem("sun"), LBParams(solver="ordered", max_sweeps=1))
    assert np.isfinite(r.residual) and not r.converged
