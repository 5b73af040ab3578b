"""The first-collision source of a beam: the exactly attenuated unscattered sun and what each cell scatters out of it.

The package docstring (``lighting.lb``, "First-collision source") says why the lattice carries only this
source's scattered light.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from foliage_tools.lighting.lb.collision import source_weights
from foliage_tools.lighting.depth import _march
from foliage_tools.lighting.lb.lattice import STEP_LENGTHS
from foliage_tools.lighting.lb.directions import NQ
from foliage_tools.lighting.lb.problem import LBProblem

#: Largest optical depth per lattice spacing used for a node: rho sigma_t = 1 ("all light interacts") would
#: be infinite; e^-40 ~ 4e-18 is zero in float32 and keeps the march finite.
EXT_MAX = 40.0


@njit(parallel=True, cache=True)
def _march_nodes(ext, dx, dy, dz, out):  # pragma: no cover - compiled
    """out[r] = integral of ext from the centre of node r along (dx, dy, dz) to the grid's edge (index units)."""
    nx, ny, nz = ext.shape
    for i in prange(nx):
        for j in range(ny):
            for k in range(nz):
                out[i, j, k] = _march(ext, i + 0.5, j + 0.5, k + 0.5, dx, dy, dz)


@njit(cache=True)
def _line_sums(ext, cx, cy, cz, out):  # pragma: no cover - compiled
    """out[r] = ext[r] + out[r - c] (0 beyond the grid): ext summed along the lattice line of c = (cx, cy, cz),
    up to and including r, visiting the nodes in the order of the line (each upstream node before its own)."""
    nx, ny, nz = ext.shape
    for a in range(nx):
        x = a if cx >= 0 else nx - 1 - a
        for b in range(ny):
            y = b if cy >= 0 else ny - 1 - b
            for e in range(nz):
                z = e if cz >= 0 else nz - 1 - e
                ux, uy, uz = x - cx, y - cy, z - cz
                up = out[ux, uy, uz] if (0 <= ux < nx and 0 <= uy < ny and 0 <= uz < nz) else 0.0
                out[x, y, z] = ext[x, y, z] + up


def optical_depths(ext: np.ndarray, d: np.ndarray, out: np.ndarray) -> None:
    """out[r] = the optical depth from node centre r to the grid's edge toward -d (``_march_nodes``).

    For d along a lattice direction c (the relightable bake's 18 bases as beams), the ray through r's centre
    runs through the centres of r - c, r - 2c, ..., crossing each of those cells over the chord l_d = |c| and
    half of r's own, so the depth is l_d (sum of ext along the line - ext(r) / 2): one pass over the grid
    (``_line_sums``) instead of a march from every node (O(n^4): 4.5 s for the 18 bases at 128^3), the same
    to round-off (tests/unit/test_lb_solver.py)."""
    c = d / np.abs(d).max()
    lattice = np.allclose(c, np.round(c), rtol=0.0, atol=1e-12)
    if lattice:
        ci = np.round(c).astype(np.int64)
        _line_sums(ext, int(ci[0]), int(ci[1]), int(ci[2]), out)
        out -= 0.5 * ext
        out *= float(np.linalg.norm(ci))
    else:
        _march_nodes(ext, -d[0], -d[1], -d[2], out)


@dataclass(frozen=True, eq=False)
class BeamFields:
    """The exact unscattered beams of a problem and their first-collision sources (``beam_fields``)."""

    direct: np.ndarray | None
    """(nx, ny, nz, K, C) float64: irradiance of the unscattered beam at each node centre (0 for non-beam rhs);
    None when not asked for (``beam_fields(..., with_direct=False)``)."""
    power: np.ndarray | None
    """(nx, ny, nz, K, C) float64: power the beam loses in each node's cell, per unit beam irradiance and
    cell volume (lattice spacing 1); None in an ``_Operator`` made without the beam outputs, once it has the power
    in its run layout."""
    coef: np.ndarray
    """(nmat, C, K, 18) float64: ``(sigma_s / sigma_t) q_i(d) |c_i|``, so the source of direction i is coef x power."""

    def source(self, q: int, mat: np.ndarray) -> np.ndarray:
        """(nx, ny, nz, C, K) post-collision source s_q of moving direction q (= lattice index q + 1)."""
        assert self.power is not None, "the beams' power was dropped (LBParams.beam_outputs False)"
        return self.coef[:, :, :, q][mat] * self.power.transpose(0, 1, 2, 4, 3)


def beam_fields(problem: LBProblem, dtype=np.float64, with_direct: bool = True) -> BeamFields:
    """The first-collision source of every beam of ``problem`` (``Boundary.beam``), exactly attenuated.

    A unit beam travelling along d enters the grid from outside. Its optical depth per lattice
    spacing at node r is ``ext = -ln(1 - rho sigma_t)`` (per channel and material; the axial
    per-step survival 1 - rho sigma_t of the lattice exactly, e^-ext; ``EXT_MAX`` caps it), and
    ``depth._march`` integrates it exactly (piecewise constant per cell, Amanatides-Woo; along a lattice
    direction, a sum along the lattice line: ``optical_depths``) from each node centre toward the light,
    giving tau_c(r). Then, with l_d = 1 / max_k |d_k| the chord of d
    through the centre of a cell and tau_up = tau_c - ext l_d / 2 the depth at the cell's upstream
    face,

        direct(r) = exp(-tau_c)                                  (the beam at the node centre)
        power(r)  = exp(-tau_up) (1 - exp(-ext l_d)) / l_d       (what the cell takes out of it)
        s_i(r)    = (sigma_s / sigma_t) q_i(d) |c_i| power(r)     (``source_weights``; post-collision)

    power is the beam's loss along the chord through the centre times the beam's cross-section
    1 / l_d per unit cell volume (-> ext exp(-tau_c) for thin cells); s_i is its scattered share
    in direction i handed to the lattice line of c_i as power, i.e. divided by that line's
    cross-section 1 / |c_i| (``collision``, "In-scattering"). For d = n_j (a lattice direction)
    and sigma_t = 1, exp(-tau_up) and 1 - exp(-ext l_d) are exactly the lattice's arriving
    unscattered f_j and its rho_j, so the scattered field is exactly that of the Kronecker
    boundary ``base_boundary(j)`` (tested).
    """
    nx, ny, nz = problem.shape
    K, C = len(problem.boundaries), problem.channels
    assert problem.brown_medium is not None  # LBProblem.__post_init__ defaults it to brown(medium)
    media = [problem.medium] + ([problem.brown_medium] if problem.brown_mask is not None and problem.brown_mask.any() else [])
    mat = np.zeros(problem.shape, np.intp)
    if len(media) == 2:
        mat[problem.brown_mask] = 1
    sig_t = np.array([m.sigma_t for m in media])  # (nmat, C)
    direct = np.zeros((nx, ny, nz, K, C), dtype) if with_direct else None
    power = np.zeros((nx, ny, nz, K, C), dtype)
    coef = np.zeros((len(media), C, K, NQ))
    L = STEP_LENGTHS[1:]
    exts = {}
    for c in range(C):
        key = tuple(sig_t[:, c])
        if key not in exts:
            with np.errstate(divide="ignore"):
                e = -np.log(np.clip(1.0 - problem.density * sig_t[mat, c], 0.0, None))
            exts[key] = np.ascontiguousarray(np.minimum(e, EXT_MAX))
    tau = np.empty(problem.shape)
    for k, b in enumerate(problem.boundaries):
        if b.beam is None:
            continue
        d = np.asarray(b.beam)
        chord = 1.0 / float(np.abs(d).max())
        for mi, m in enumerate(media):
            for c in range(C):
                st = m.sigma_t[c]
                if st > 0.0:
                    coef[mi, c, k] = (m.sigma_s[c] / st) * source_weights(d, m.g[c], m.phase, "ordinates") * L
        done = {}
        for c in range(C):
            key = tuple(sig_t[:, c])
            if key not in done:
                ext = exts[key]
                optical_depths(ext, d, tau)
                up = np.maximum(tau - 0.5 * chord * ext, 0.0)
                done[key] = (np.exp(-tau) if direct is not None else None, np.exp(-up) * -np.expm1(-chord * ext) / chord)
            if direct is not None:
                direct[..., k, c] = done[key][0]
            power[..., k, c] = done[key][1]
    return BeamFields(direct, power, coef)
