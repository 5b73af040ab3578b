"""The in-place ordered (Gauss-Seidel) sweep of the lattice-Boltzmann solver (numba), ``solver="ordered"``.

Why: plain (Jacobi) sweeps move light one node per sweep, so from the unscattered start the residual of the
relightable bake falls about linearly until the once-scattered light has crossed the grid and then drops: the
sweep count tracks the grid's longest edge (64^3: 64-68 sweeps, 128^3: 128-132), although the scattering
itself contracts fast (source iteration with exact line transport on tree_small: a factor ~7 per order).
Visiting the nodes in lexicographic order (x, y, z ascending; descending on the next pass) and writing each
post-collision value straight into its target slot of the *same* field carries every direction whose step is
lexicographically positive across the whole grid in one pass (the opposite ones on the next), so the passes
converge per order of scattering instead of per node crossed: tree_small, relightable bake, change per pass
1e-2, 1e-2, 6e-4, 5e-5, 4e-6 at 64^3 and 1e-2, 1e-2, 6e-4, 6e-5, 9e-6 at 128^3 (fp16): the same at both
sizes (``solvers._ordered``). One field, no copy: every slot (node, direction) is written once per pass by its
unique upstream node and read once, when its node is visited, so in-place is exact.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from foliage_tools.lighting.lb.directions import _CX, _CY, _CZ, NAXIAL_PAIRS, NH
from foliage_tools.lighting.storage import convert, load


@njit(parallel=True, fastmath=True, cache=True)
def _sweep_ordered(f, rho, rhod, mat, AE, AO, forward, pw, cq, use_src):  # pragma: no cover - compiled
    """One in-place ordered sweep of ``f`` (the block layout of ``_Operator``: (nx, NB, 18, C, G nz, K)).

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
    for c in prange(C):
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
