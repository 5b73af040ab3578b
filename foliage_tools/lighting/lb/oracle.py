"""The test oracle of the lattice-Boltzmann kernels: one update of geist2008 eq. (2) in plain numpy."""

from __future__ import annotations

import numpy as np

from foliage_tools.lighting.lb.collision import unit_moving_block
from foliage_tools.lighting.lb.lattice import DIRECTIONS
from foliage_tools.lighting.lb.beam import beam_fields
from foliage_tools.lighting.lb.directions import NQ, power_weights
from foliage_tools.lighting.lb.problem import LBProblem


def _reference_step(f: np.ndarray, problem: LBProblem) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One update of geist2008 eq. (2) in plain numpy (the kernels are tested against it).

    Parameters
    ----------
    f : (nx, ny, nz, 19, K, C) float64 arriving densities (f_0 = 0 after the previous step).

    Returns
    -------
    f_next : (nx, ny, nz, 19, K, C), inflow slots holding the boundary densities
    absorbed : (nx, ny, nz, K, C), the power removed at each node (booked into f_0 and zeroed,
        geist2008 sec. 3), in ``power_weights`` units
    outflow : (K, C), power that left the grid

    The collision is ``f_i + sum_j A_ij rho_j f_j`` (``collision.unit_moving_block`` and
    ``step_density`` of the problem's lattice: on ``geist2008`` this is f + rho Omega f of eqs.
    (5)-(9) with f_0 removed), plus the first-collision source of any beam (``beam_fields``).
    """
    from foliage_tools.lighting.lb.collision import step_density

    rho = problem.density
    assert problem.brown_medium is not None  # LBProblem.__post_init__ defaults it to brown(medium)
    media = [problem.medium, problem.brown_medium]
    A = np.array([unit_moving_block(m, problem.lattice) for m in media])  # (2, C, 18, 18)
    mat = np.zeros(rho.shape, int) if problem.brown_mask is None else problem.brown_mask.astype(int)
    rq = step_density(rho, problem.lattice)  # (nx, ny, nz, 18)
    moving = f[..., 1:, :, :]
    post = np.zeros_like(f)
    post[..., 1:, :, :] = moving + np.einsum("xyzcij,xyzjkc->xyzikc", A[mat], rq[..., :, None, None] * moving)
    if any(b.beam is not None for b in problem.boundaries):
        bf = beam_fields(problem)
        for q in range(NQ):
            post[..., q + 1, :, :] += bf.source(q, mat).transpose(0, 1, 2, 4, 3)
    wq = power_weights(problem.lattice)
    sig_a = np.array([m.sigma_a for m in media])[mat]  # (nx, ny, nz, C)
    absorbed = np.einsum("xyzj,xyzjkc->xyzkc", rq * wq, moving) * sig_a[..., None, :]
    nxt = np.zeros_like(f)
    outflow = np.zeros(f.shape[-2:])
    bnd = np.array([b.inflow for b in problem.boundaries])  # (K, 18)
    for i in range(1, 19):
        c = DIRECTIONS[i]
        dst = tuple(slice(1, None) if v > 0 else slice(None, -1) if v < 0 else slice(None) for v in c)
        src = tuple(slice(None, -1) if v > 0 else slice(1, None) if v < 0 else slice(None) for v in c)
        nxt[..., i, :, :] = bnd[:, i - 1][:, None]  # inflow slots; overwritten where an upstream node exists
        moved = post[src + (i,)]
        nxt[dst + (i,)] = moved
        outflow += wq[i - 1] * (post[..., i, :, :].sum(axis=(0, 1, 2)) - moved.sum(axis=(0, 1, 2)))
    return nxt, absorbed, outflow
