"""Unscattered light in one pass: the never-scattered field of the lattice, exactly, without iterating it."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from foliage_tools.lighting.lb.collision import diagonal_density
from foliage_tools.lighting.lb.beam import beam_fields
from foliage_tools.lighting.lb.directions import _CX, _CY, _CZ, NQ
from foliage_tools.lighting.lb.problem import LBProblem


@njit(cache=True)
def _transmit(att, cx, cy, cz, out):  # pragma: no cover - compiled
    """out[r, c] = density arriving at r along c = (cx, cy, cz) per unit inflow, never scattered.

    The steady state of ``f_i(r) = f_i(r - c_i) * att(r - c_i)`` with f_i = 1
    in inflow slots, filled in the order of the beam so every upstream value
    is final when it is read (one pass, exact; no iteration).
    """
    nx, ny, nz, C = att.shape
    for a in range(nx):
        x = a if cx >= 0 else nx - 1 - a
        for b in range(ny):
            y = b if cy >= 0 else ny - 1 - b
            for e in range(nz):
                z = e if cz >= 0 else nz - 1 - e
                ux, uy, uz = x - cx, y - cy, z - cz
                if ux < 0 or ux >= nx or uy < 0 or uy >= ny or uz < 0 or uz >= nz:
                    for c in range(C):
                        out[x, y, z, c] = 1.0
                else:
                    for c in range(C):
                        out[x, y, z, c] = out[ux, uy, uz, c] * att[ux, uy, uz, c]


@njit(parallel=True, cache=True)
def _add_transmitted(energy, t, b):  # pragma: no cover - compiled
    """energy[..., k, :] += b[k] t for the right-hand sides k with inflow b[k] != 0 along this direction.

    t (nx, ny, nz, C); energy (nx, ny, nz, K, C); one parallel pass (numpy's strided updates of a 128^3 field
    with 18 bases took 2.1 s)."""
    nx, ny, nz, C = t.shape
    for x in prange(nx):
        for y in range(ny):
            for z in range(nz):
                for k in range(b.size):
                    if b[k] != 0:
                        for c in range(C):
                            energy[x, y, z, k, c] += b[k] * t[x, y, z, c]


def unscattered_energy(problem: LBProblem, dtype: str = "float32") -> np.ndarray:
    """Energy density u_unscattered (nx, ny, nz, K, C) of never-scattered light, exactly, in one pass.

    Boundary inflow: the unscattered lattice (``problem.unscattered()``: sigma_s = 0, sigma_a =
    sigma_t) has the diagonal moving block ``-sigma_t I`` (geist2008 eqs. (5)-(7) with sigma_s =
    0), so every direction evolves alone: geist2008 eq. (2) becomes ``f_i(r + c_i) = (1 -
    rho_i(r) sigma_t) f_i(r)`` (rho_i = ``collision.step_density``), a product of per-node factors
    along the upstream line. Its steady state is that product, which ``_transmit`` builds in one
    ordered pass per direction instead of iterating the whole lattice (the same numbers as
    ``solve(problem.unscattered())`` to the solver's tolerance; tested). u = sum_i b_i f_i for
    each boundary condition's inflow b. A beam (``Boundary.beam``): the exactly attenuated beam
    at each node centre, ``beam_fields(problem).direct``.
    """
    nx, ny, nz = problem.shape
    bnd = np.array([b.inflow for b in problem.boundaries], dtype=np.float64)  # (K, 18)
    energy = np.zeros((nx, ny, nz, len(problem.boundaries), problem.channels), dtype)
    for q, t in _transmittances(problem, bnd.any(axis=0), dtype):
        _add_transmitted(energy, t, np.ascontiguousarray(bnd[:, q], dtype=dtype))
    if any(b.beam is not None for b in problem.boundaries):
        direct = beam_fields(problem).direct
        assert direct is not None  # asked for (the default)
        energy += direct.astype(dtype)
    return energy


def _attenuations(problem: LBProblem, dtype) -> tuple[np.ndarray, np.ndarray]:
    """Per-step survival 1 - rho_q sigma_t (nx, ny, nz, C) of the axial and of the non-axial directions."""
    out = []
    for rho in (problem.density, diagonal_density(problem.density) if problem.lattice == "ordinates" else problem.density):
        att = 1.0 - rho[..., None] * np.array(problem.medium.sigma_t, dtype=np.float64)  # green nodes
        if problem.brown_mask is not None:
            assert problem.brown_medium is not None  # LBProblem.__post_init__ defaults it to brown(medium)
            att[problem.brown_mask] = 1.0 - rho[problem.brown_mask][:, None] * np.array(problem.brown_medium.sigma_t)
        out.append(np.ascontiguousarray(att, dtype=dtype))
    return out[0], out[1]


def _transmittances(problem: LBProblem, wanted: np.ndarray, dtype):
    """Yield (q, t_q) for the wanted directions q: t_q (nx, ny, nz, C) from ``_transmit`` (one buffer, reused)."""
    if not np.any(wanted):
        return
    att = _attenuations(problem, dtype)
    t = np.empty(att[0].shape, dtype)
    for q in range(NQ):
        if wanted[q]:
            _transmit(att[q >= 6], int(_CX[q]), int(_CY[q]), int(_CZ[q]), t)
            yield q, t
