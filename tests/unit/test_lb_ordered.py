"""``solver="ordered"``: in-place sweeps in alternating lexicographic order reach the plain iteration's fixed point."""

from __future__ import annotations

import numpy as np
import pytest

from numba import njit

from foliage_tools.lighting.lb.collision import Medium, brown
from foliage_tools.lighting.lb import (
    LBParams,
    LBProblem,
    _Operator,
    base_boundary,
    relighting_boundaries,
    solve,
    sun_boundary,
    sun_source,
)
from foliage_tools.lighting.lb.directions import _CX, _CY, _CZ, NAXIAL_PAIRS, NH
from foliage_tools.lighting.lb.kernels_ordered import _sweep_ordered_rows
from foliage_tools.lighting.lb.storage import convert, from_storage, load


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


@njit(cache=True)
def _node_by_node(f, rho, rhod, mat, AE, AO, forward, pw, cq, use_src):  # pragma: no cover - compiled
    """The reference: one in-place ordered sweep of ``f`` (the block layout of ``_Operator``: (nx, NB, 18, C, G nz,
    K)) visiting the nodes one by one, as the product's kernel did before it worked a row at a time.

    Nodes are visited in lexicographic order of (x, y, z) (``forward``) or its reverse; at each occupied
    node the collision f_i + sum_j A_ij rho_j f_j (the parity split of ``_collide_pairs``: AE, AO (nmat, C,
    9, 9)) plus, with ``use_src``, the beams' first-collision source cq[m, c, i, k] pw[x, y // G, c, l K + k]
    is pushed into slot (r + c_i, i) of f itself; an empty node (91 % of a crown's box) only moves its 18
    values on, copied as stored (no rounding). Inflow slots are never written. Channels run in parallel
    (independent right-hand sides), the K right-hand sides of a channel are the vector lanes. Convergence
    is measured by a plain sweep (``_Operator.sweep``), not here.
    """
    nx, nb, nq, C, gnz, K = f.shape
    ny = rho.shape[1]
    nz = rho.shape[2]
    G = gnz // nz
    for c in range(C):
        fl = np.empty((nq, K), dtype=rho.dtype)
        sv = np.empty((NH, K), dtype=rho.dtype)
        dv = np.empty((NH, K), dtype=rho.dtype)
        ev = np.empty(K, dtype=rho.dtype)
        ov = np.empty(K, dtype=rho.dtype)
        tbs = np.empty(3, dtype=np.int64)  # block and run offset of rows y - 1, y, y + 1: no division per node
        tos = np.empty(3, dtype=np.int64)
        for a in range(nx):
            x = a if forward else nx - 1 - a
            for b in range(ny):
                y = b if forward else ny - 1 - b
                yb = y // G
                yo = (y % G) * nz
                for d in range(3):
                    ty = min(max(y + d - 1, 0), ny - 1)  # (clamped rows are never targets: checked below)
                    tbs[d] = ty // G
                    tos[d] = (ty % G) * nz
                for e in range(nz):
                    z = e if forward else nz - 1 - e
                    l = yo + z
                    r = rho[x, y, z]
                    if r == 0:  # nothing collides: each direction's value moves on as it is stored
                        for i in range(nq):
                            tx = x + _CX[i]
                            ty = y + _CY[i]
                            tz = z + _CZ[i]
                            if tx < 0 or tx >= nx or ty < 0 or ty >= ny or tz < 0 or tz >= nz:
                                continue  # the light leaves the grid
                            tb = tbs[_CY[i] + 1]
                            tl = tos[_CY[i] + 1] + tz
                            for k in range(K):
                                f[tx, tb, i, c, tl, k] = f[x, yb, i, c, l, k]
                        continue
                    for j in range(nq):
                        for k in range(K):
                            fl[j, k] = load(f[x, yb, j, c, l, k])
                    m = mat[x, y, z]
                    rd = rhod[x, y, z]
                    for p in range(NH):
                        rp = r if p < NAXIAL_PAIRS else rd
                        for k in range(K):
                            va = fl[2 * p, k]
                            vb = fl[2 * p + 1, k]
                            sv[p, k] = rp * (va + vb)
                            dv[p, k] = rp * (va - vb)
                    for p in range(NH):
                        for k in range(K):
                            ev[k] = 0.0
                            ov[k] = 0.0
                        for q in range(NH):
                            ca = AE[m, c, p, q]
                            cb = AO[m, c, p, q]
                            for k in range(K):
                                ev[k] += ca * sv[q, k]
                                ov[k] += cb * dv[q, k]
                        for k in range(K):
                            fl[2 * p, k] += ev[k] + ov[k]
                            fl[2 * p + 1, k] += ev[k] - ov[k]
                    if use_src:
                        for i in range(nq):
                            for k in range(K):
                                fl[i, k] += cq[m, c, i, k] * pw[x, yb, c, l * K + k]
                    for i in range(nq):
                        tx = x + _CX[i]
                        ty = y + _CY[i]
                        tz = z + _CZ[i]
                        if tx < 0 or tx >= nx or ty < 0 or ty >= ny or tz < 0 or tz >= nz:
                            continue
                        dst = f[tx, tbs[_CY[i] + 1], i, c, tos[_CY[i] + 1] + tz]
                        for k in range(K):
                            dst[k] = convert(fl[i, k], dst)


@pytest.mark.parametrize("storage", ["fp32", "fp16"])
@pytest.mark.parametrize("shape, bounds", [
    ((9, 7, 5), (sun_boundary((0.3, 0.2, 0.9)),)),
    ((6, 11, 4), (sun_source((0.3, -0.2, -0.9)), base_boundary(7))),
    ((5, 23, 30), (sun_source((-0.6, 0.5, 0.62)),)),
], ids=["sun", "beam+base", "blocks"])
def test_row_kernel_is_the_node_by_node_sweep(shape, bounds, storage):
    """The row kernel against the sweep visiting the nodes one by one, forward and backward: two materials, empty
    rows and empty nodes in occupied rows, boundary inflow and beams, two right-hand sides, several blocks of rows
    (``blocks``: nz 30, 23 rows). The same sweep with its arithmetic in another order: float32 round-off, ~1e-7 of
    the largest value (2e-6 allows a sum of 19 terms each off by eps); fp16 stores the same rounding of values that
    differ by that, so a stored value can flip by one half-ulp, 2^-11 of itself (and 2^-11 of 2^-11 around it)."""
    rng = np.random.default_rng(7)
    med = Medium(sigma_a=(0.1, 0.3, 0.02), sigma_s=(0.85, 0.6, 0.97), g=(0.4, -0.7, 0.0))
    rho = rng.uniform(0.05, 0.9, shape)
    rho[rng.uniform(size=shape) < 0.5] = 0.0
    rho[1] = 0.0  # a slab of empty rows
    pb = LBProblem(rho, med, bounds, brown_mask=rng.uniform(size=shape) < 0.2)
    op = _Operator(pb, "float32", storage)
    for forward in (True, False):
        f = op.unscattered(pb)
        g = f.copy()
        _sweep_ordered_rows(f, op.rho, op.rhod, op.mat, op.A, op.AE, op.AO, forward, op.pw, op.cE, op.cO, op.use_src)
        _node_by_node(g, op.rho, op.rhod, op.mat, op.AE, op.AO, forward, op.pw, op.cq, op.use_src)
        a, b, start = from_storage(f), from_storage(g), from_storage(op.unscattered(pb))
        assert np.abs(b - start).max() > 0.1 * np.abs(b).max()  # the sweep moved the light
        if storage == "fp32":
            np.testing.assert_allclose(a, b, rtol=0, atol=2e-6 * np.abs(b).max())
        else:
            np.testing.assert_allclose(a, b, rtol=2.0**-10, atol=2.0**-22)
