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

from foliage_tools.lighting.lb.directions import _CX, _CY, _CZ, NH
from foliage_tools.lighting.lb.kernels_collide import _collide_pairs
from foliage_tools.lighting.lb.kernels_stream import _copy
from foliage_tools.lighting.lb.storage import convert, load


@njit(fastmath=True, cache=True)
def _move_run(src, dst, cz, K, nz, same):  # pragma: no cover - compiled
    """dst[(z + cz) K + k] = src[z K + k] for every node z whose target z + cz is in the row; ``same``: src and dst are
    one run (the row's own opposite direction), copied in the order that reads each value before it is overwritten."""
    z0 = max(0, -cz)
    z1 = nz - max(0, cz)
    if same and cz > 0:
        for z in range(z1 - 1, z0 - 1, -1):
            for k in range(K):
                dst[(z + cz) * K + k] = src[z * K + k]
    else:  # zero-based views: an index l + d of unknown sign would keep the loop scalar (negative-index wrap)
        _copy(dst[(z0 + cz) * K : (z1 + cz) * K], src[z0 * K : z1 * K])


@njit(parallel=True, fastmath=True, cache=True)
def _sweep_ordered_rows(f, rho, rhod, mat, A, AE, AO, forward, pw, cE, cO, use_src):  # pragma: no cover - compiled
    """One in-place ordered sweep of ``f`` (the block layout of ``_Operator``: (nx, NB, 18, C, G nz, K)), a z-row at
    a time.

    The sweep it computes: nodes visited in lexicographic order of (x, y, z) (``forward``) or its reverse, each
    occupied node's collision f_i + sum_j A_ij rho_j f_j (A (nmat, C, 18, 18) the unit moving block, rho_j the axial
    rho or the non-axial rhod; plus, with ``use_src``, the beams' first-collision source) pushed into slot
    (r + c_i, i) of f itself, an empty node's 18 values moved on as stored; inflow slots never written. Channels
    run in parallel (independent right-hand sides), the K right-hand sides of a channel are the vector lanes.

    How, a row at a time: within a row only the z-step along the visiting order (+z forward, -z backward:
    direction ``js``) carries light to a node visited later in the same row; every other slot a node reads holds,
    when its row is visited, what it would hold when the node itself is (written by earlier rows of this sweep,
    or left by the last one). So a row's 18 runs are read once; everything but f_js collides for all its nodes at
    once (the parity split of ``_collide_pairs``: AE, AO (nmat, C, 9, 9); the source's parity parts cE, cO
    (nmat, C, 9, G nz K) tiled along the run, as ``_Operator`` holds them); then f_js goes node by node in the
    visiting order, f_js(z + step) = post_js(z), each value rounded as the next node would read it stored, and
    its column A[:, js] is added to the other directions; then the post-collision runs are pushed into their
    target rows (into this row for +-z). An empty row only moves its values on, as stored. A node-by-node
    implementation is the reference of the tests (``test_lb_ordered``). Convergence is measured by a plain sweep
    (``_Operator.sweep``), not here.
    """
    nx, nb, nq, C, gnz, K = f.shape
    ny = rho.shape[1]
    nz = rho.shape[2]
    G = gnz // nz
    nmat = AE.shape[0]
    n = nz * K
    js = 4 if forward else 5  # direction +z (index 4) or -z (5): the in-row step along the visiting order
    jo = js ^ 1
    step = 1 if forward else -1
    f5 = f.reshape((nx, nb, nq, C, gnz * K))
    for c in prange(C):
        V = np.empty((nq, C, n), dtype=rho.dtype)  # the row's values (channel c), f_js zeroed
        P = np.empty((nq, n), dtype=rho.dtype)  # post-collision values
        FS = np.empty(n, dtype=rho.dtype)  # f_js arriving at each node
        col = np.empty((nq, nz), dtype=rho.dtype)  # rho A[m, c, i, js] of each node
        rexp = np.empty((nmat, 2, n), dtype=rho.dtype)
        pexp = np.zeros((nmat, C, n if use_src and nmat > 1 else 1), dtype=rho.dtype)
        has = np.zeros(nmat, dtype=np.bool_)
        ae = np.empty((NH, NH), dtype=rho.dtype)
        ao = np.empty((NH, NH), dtype=rho.dtype)
        buf = np.empty(2 * NH * n, dtype=rho.dtype)  # S, D and E, O of the occupied run, (9, its length) each
        prod = np.empty(2 * NH * n, dtype=rho.dtype)
        extra = np.empty(2 * NH * n, dtype=rho.dtype)
        tbs = np.empty(3, dtype=np.int64)
        tos = np.empty(3, dtype=np.int64)
        one = np.ones(1, dtype=rho.dtype)[0]  # (a float64 literal would promote the recurrence)
        for a in range(nx):
            x = a if forward else nx - 1 - a
            for b in range(ny):
                y = b if forward else ny - 1 - b
                yb = y // G
                o = (y % G) * n
                for d in range(3):
                    ty = min(max(y + d - 1, 0), ny - 1)  # (clamped rows are never targets: checked below)
                    tbs[d] = ty // G
                    tos[d] = (ty % G) * n
                rr = rho[x, y]
                mm = mat[x, y]
                for m in range(nmat):
                    has[m] = False
                for z in range(nz):
                    if rr[z] > 0:
                        has[mm[z]] = True
                occupied = False
                for m in range(nmat):
                    occupied = occupied or has[m]
                if not occupied:  # nothing collides: every value moves on as it is stored
                    for i in range(nq):
                        tx = x + _CX[i]
                        ty = y + _CY[i]
                        if tx < 0 or tx >= nx or ty < 0 or ty >= ny:
                            continue  # the light leaves the grid
                        src = f5[x, yb, i, c, o : o + n]
                        if i == js:  # along the row in the visiting order each node passes on what it received:
                            first = 0 if forward else nz - 1  # the row's first node's (inflow) value, everywhere
                            for k in range(K):
                                v = src[first * K + k]
                                for z in range(nz):
                                    src[z * K + k] = v
                            continue
                        t = tos[_CY[i] + 1]
                        _move_run(src, f5[tx, tbs[_CY[i] + 1], i, c, t : t + n], _CZ[i], K, nz, i == jo)
                    continue
                # the occupied nodes z0 .. z1 - 1 (only they collide); there the densities per material (0 on other
                # materials' nodes) and f_js's column
                z0 = nz
                z1 = 0
                for z in range(nz):
                    if rr[z] > 0:
                        z0 = min(z0, z)
                        z1 = z + 1
                l0 = z0 * K
                l1 = z1 * K
                m1 = l1 - l0
                Sb = buf[: NH * m1].reshape((NH, m1))  # exactly the run's length: _pair_product runs over its columns
                Db = buf[NH * m1 : 2 * NH * m1].reshape((NH, m1))
                Eb = prod[: NH * m1].reshape((NH, m1))
                Ob = prod[NH * m1 : 2 * NH * m1].reshape((NH, m1))
                for m in range(nmat):
                    for z in range(z0, z1):
                        own = mm[z] == m
                        v = rr[z] if own else 0.0
                        vd = rhod[x, y, z] if own else 0.0
                        for k in range(K):
                            rexp[m, 0, z * K + k] = v
                            rexp[m, 1, z * K + k] = vd
                            if use_src and nmat > 1:  # (this channel's only: the others are other threads')
                                pexp[m, c, z * K + k] = pw[x, yb, c, o + z * K + k] if own else 0.0
                for z in range(nz):
                    m = mm[z]
                    for i in range(nq):
                        col[i, z] = rr[z] * A[m, c, i, js]
                for i in range(nq):
                    src = f5[x, yb, i, c, o : o + n]
                    vi = V[i, c]
                    if i == js:
                        for l in range(n):
                            vi[l] = 0.0
                    else:
                        for l in range(n):
                            vi[l] = load(src[l])
                if nmat == 1:
                    _collide_pairs(V, c, l0, m1, rexp, l0, has, AE, AO, ae, ao, Sb, Db, Eb, Ob, extra, pw[x, yb : yb + 1],
                                   o + l0, cE, cO, K == 1, use_src)
                else:
                    _collide_pairs(V, c, l0, m1, rexp, l0, has, AE, AO, ae, ao, Sb, Db, Eb, Ob, extra, pexp, l0, cE, cO,
                                   K == 1, use_src)
                for p in range(NH):
                    va = V[2 * p, c]
                    vb = V[2 * p + 1, c]
                    ep = Eb[p]
                    op = Ob[p]
                    pa = P[2 * p]
                    pb = P[2 * p + 1]
                    for l in range(l0):
                        pa[l] = va[l]
                        pb[l] = vb[l]
                    for l in range(m1):
                        pa[l0 + l] = va[l0 + l] + ep[l] + op[l]
                        pb[l0 + l] = vb[l0 + l] + ep[l] - op[l]
                    for l in range(l1, n):
                        pa[l] = va[l]
                        pb[l] = vb[l]
                # f_js node by node in the visiting order, from what the row's first node holds (an inflow slot)
                first = 0 if forward else nz - 1
                src = f5[x, yb, js, c, o : o + n]
                pj = P[js]
                for k in range(K):
                    FS[first * K + k] = load(src[first * K + k])
                for e in range(nz):
                    z = e if forward else nz - 1 - e
                    g = one + col[js, z]
                    for k in range(K):
                        l = z * K + k
                        v = pj[l] + g * FS[l]
                        pj[l] = v
                        if e + 1 < nz:  # the next node reads it as stored (rounded, with fp16 storage)
                            FS[(z + step) * K + k] = load(convert(v, src))
                for i in range(nq):
                    if i == js:
                        continue
                    pi = P[i]
                    ci = col[i]
                    for z in range(nz):
                        w = ci[z]
                        for k in range(K):
                            pi[z * K + k] += w * FS[z * K + k]
                # push the post-collision runs into their target rows
                for i in range(nq):
                    tx = x + _CX[i]
                    ty = y + _CY[i]
                    if tx < 0 or tx >= nx or ty < 0 or ty >= ny:
                        continue
                    t = tos[_CY[i] + 1]
                    dst = f5[tx, tbs[_CY[i] + 1], i, c, t : t + n]
                    cz = _CZ[i]
                    za = max(0, -cz)  # nodes whose target z + cz is in the row
                    zb = nz - max(0, cz)
                    dd = dst[(za + cz) * K : (zb + cz) * K]
                    pi = P[i, za * K : zb * K]
                    for l in range(dd.size):
                        dd[l] = convert(pi[l], dd)
