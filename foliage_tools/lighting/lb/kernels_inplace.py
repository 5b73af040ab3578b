"""Two plain sweeps in place: the AA pattern (Bailey et al. 2009) of the lattice-Boltzmann solver (numba).

Why: the push sweep (``kernels_sweep``) reads every value of one field and writes it, shifted, into a second,
and each target cache line is first read for ownership; with few right-hand sides that streaming is most of the
sweep (``benchmarks/bench_lb_streaming_pattern.py``). The AA pattern writes each value back where a node read
it, so a pair of sweeps moves every value once each way through memory, in one field:

* even step (``_aa_even``): node r reads its own slots f_i(r), collides (geist2008 eq. (2), f_0 removed, sec. 3)
  and writes post_i(r), the value f_i(r + c_i) of the next state, into its own slot opposite to i. Between the
  steps the state is held *swapped*: f_i(s) at slot (s - c_i, opposite(i)).
* odd step (``_aa_odd``): node r gathers f_i(r) from slot (r - c_i, opposite(i)), collides and writes post_i(r)
  into slot (r + c_i, i), where the natural layout keeps f_i(r + c_i). The 18 slots node r reads are the 18 it
  writes and no other node touches them, so the step is exact in place in any order and in parallel.

Boundaries as in the push sweep (``lighting.lb``): an inflow slot holds b_i for ever. The even step writes
post_i(r) of a node whose r + c_i is outside the grid into slot (r, opposite(i)), which is the natural layout's
inflow slot of opposite(i): it puts b back there afterwards (the light left the grid). The odd step takes b_i
for f_i(r) when r - c_i is outside, and drops post_i(r) when r + c_i is. After a pair the field is in the
natural layout, every slot as two push sweeps leave it to float rounding (the pairs collide by the symmetry
blocks of ``kernels_collide._collide_sym``, the push sweep by the (9 x 9) products; a test holds the two together).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from foliage_tools.lighting.lb.directions import _CX, _CY, _CZ, NH
from foliage_tools.lighting.lb.kernels_collide import SYM_RUN, _block_occupancy, _collide_block_sym
from foliage_tools.lighting.lb.kernels_stream import _copy, _fill
from foliage_tools.lighting.lb.storage import convert, load


@njit(fastmath=True, cache=True)
def _scratch(nmat, C, R, use_src, rho):  # pragma: no cover - compiled
    """A thread's scratch for blocks of R values: the E_p, O_p rows (``_collide_run``), the densities and beam power
    per material (``_block_occupancy``), and 0 in the arithmetic's dtype (rho's)."""
    EO = np.empty(4 * NH * SYM_RUN, dtype=rho.dtype)
    rexp = np.empty((nmat, 2, R), dtype=rho.dtype)
    pexp = np.zeros((nmat, C, R if use_src and nmat > 1 else 1), dtype=rho.dtype)
    has = np.zeros(nmat, dtype=np.bool_)
    return EO, rexp, pexp, has, np.zeros(1, dtype=rho.dtype)[0]


@njit(fastmath=True, cache=True)
def _put(dst, s, d, a, b, l0, l1, ep, op, sg, zero):  # pragma: no cover - compiled
    """dst[l + d] = post(l) for l in [a, b): max(s[l] + ep[l - l0] + sg op[l - l0], 0) on the collided run [l0, l1)
    (``_aa_even`` says why no lower than 0), s[l] as stored elsewhere."""
    c1 = min(b, l0)
    if c1 > a:
        _copy(dst[a + d : c1 + d], s[a:c1])
    c0 = max(a, l0)
    c1 = min(b, l1)
    if c1 > c0:
        dd = dst[c0 + d : c1 + d]
        ss = s[c0:c1]
        ee = ep[c0 - l0 : c1 - l0]
        oo = op[c0 - l0 : c1 - l0]
        for l in range(c1 - c0):
            dd[l] = convert(max(load(ss[l]) + ee[l] + sg * oo[l], zero), dd)
    c0 = max(a, l1)
    if b > c0:
        _copy(dst[c0 + d : b + d], s[c0:b])


@njit(parallel=True, fastmath=True, cache=True)
def _aa_even(f, rho, rhod, mat, Q, pw, cE, cO, use_src, binf):  # pragma: no cover - compiled
    """The even step of the AA pattern, in place: f (natural layout) -> the next state, swapped (module docstring).

    f : (nx, NB, 18, C, G nz, K), the block layout of ``_Operator`` (G nz K <= ``SYM_MAX_RUN``); rho, rhod, mat, pw, cE, cO,
    use_src as in ``_sweep_blocks``; Q (nmat, C, 30) the collision's symmetry blocks (``_symmetry_blocks``,
    ``_collide_sym``); binf : (18, K) the inflow values b_i as stored.
    """
    nx, nb, nq, C, gnz, B = f.shape
    ny = rho.shape[1]
    nz = rho.shape[2]
    G = gnz // nz
    Lr = nz * B
    R = G * Lr
    f5 = f.reshape((nx, nb, nq, C, R))
    for x in prange(nx):
        EO, rexp, pexp, has, zero = _scratch(Q.shape[0], C, R, use_src, rho)
        for blk in range(nb):
            y0 = blk * G
            nrows = min(G, ny - y0)
            F = f5[x, blk]
            l0, l1 = _block_occupancy(rho, rhod, mat, pw, x, blk, G, B, use_src, rexp, pexp, has)
            n = l1 - l0
            for c in range(C):
                if n > 0:
                    _collide_block_sym(F, c, l0, n, 0, rexp, has, Q, EO, pw, x, blk, pexp, cE, cO, B == 1, use_src)
                for p in range(NH):
                    a = F[2 * p, c]
                    b = F[2 * p + 1, c]
                    # slot 2p <- post_2p+1 = f_2p+1 + E_p - O_p, slot 2p+1 <- post_2p = f_2p + E_p + O_p, no lower than
                    # 0: for a state f >= 0 the exact value is >= 0 (the update matrix is non-negative, ``lighting.lb``
                    # "Stability policy") and the symmetry-adapted products leave round-off of either sign (~1e-7
                    # of the node's values in float32) where it is 0; a node that does not collide swaps its pair
                    # as stored (no rounding)
                    for l in range(l0):
                        t = a[l]
                        a[l] = b[l]
                        b[l] = t
                    ep = EO[p * SYM_RUN : p * SYM_RUN + n]
                    op = EO[(NH + p) * SYM_RUN : (NH + p) * SYM_RUN + n]
                    aa = a[l0:l1]
                    bb = b[l0:l1]
                    for l in range(n):
                        va = load(aa[l])
                        vb = load(bb[l])
                        aa[l] = convert(max(vb + ep[l] - op[l], zero), aa)
                        bb[l] = convert(max(va + ep[l] + op[l], zero), bb)
                    for l in range(l1, nrows * Lr):
                        t = a[l]
                        a[l] = b[l]
                        b[l] = t
            # inflow slots (r, i), r - c_i outside the grid, now hold post_opposite(i)(r), light that left: b_i again
            for i in range(nq):
                bi = binf[i]
                cz = _CZ[i]
                xout = x - _CX[i] < 0 or x - _CX[i] >= nx
                for g in range(nrows):
                    sy = y0 + g - _CY[i]
                    row = F[i, :, g * Lr : (g + 1) * Lr]
                    for c in range(C):
                        if xout or sy < 0 or sy >= ny:
                            _fill(row[c], bi, B)
                        elif cz > 0:
                            _fill(row[c, :B], bi, B)
                        elif cz < 0:
                            _fill(row[c, Lr - B :], bi, B)


@njit(parallel=True, fastmath=True, cache=True)
def _aa_odd(f, rho, rhod, mat, Q, pw, cE, cO, use_src, binf, RP):  # pragma: no cover - compiled
    """The odd step of the AA pattern, in place: f (swapped, as ``_aa_even`` left it) -> the next state in the
    natural layout (module docstring). Arguments as ``_aa_even``'s, and RP the row distance of the gathered runs
    (``sym_row_stride``).

    Rows of a block whose neighbour row along c_i is in the same block move as one flat run shifted by
    c_y nz K + c_z K (the z-faces' values wrap into the next or previous row there: gathered ones are replaced by
    b_i, scattered ones land on inflow slots, which get b_i back); a row whose neighbour is in the next or
    previous block moves on its own.
    """
    nx, nb, nq, C, gnz, B = f.shape
    ny = rho.shape[1]
    nz = rho.shape[2]
    G = gnz // nz
    Lr = nz * B
    R = G * Lr
    f5 = f.reshape((nx, nb, nq, C, R))
    for x in prange(nx):
        EO, rexp, pexp, has, zero = _scratch(Q.shape[0], C, R, use_src, rho)
        gat = np.empty((nq, C, RP), dtype=f.dtype)  # f_i(r) of the block's nodes, gathered (as stored)
        sgn = np.empty(2, dtype=rho.dtype)  # +1 / -1 in the arithmetic's dtype (a float64 sign would promote)
        sgn[0] = 1.0
        sgn[1] = -1.0
        for blk in range(nb):
            y0 = blk * G
            nrows = min(G, ny - y0)
            l0, l1 = _block_occupancy(rho, rhod, mat, pw, x, blk, G, B, use_src, rexp, pexp, has)
            n = l1 - l0
            for c in range(C):
                # gather f_i(r) from slot (r - c_i, opposite(i)); b_i where r - c_i is outside the grid
                for i in range(nq):
                    sx = x - _CX[i]
                    cy = _CY[i]
                    cz = _CZ[i]
                    bi = binf[i]
                    gi = gat[i, c]
                    if sx < 0 or sx >= nx:
                        _fill(gi[: nrows * Lr], bi, B)
                        continue
                    ga = max(0, cy)  # rows whose upstream row is in this block
                    gb = min(nrows, nrows + cy)
                    if gb > ga:
                        d = cy * Lr + cz * B  # gi[l] = S[l - d]
                        a = max(ga * Lr, d)
                        b = min(gb * Lr, R + d)
                        _copy(gi[a:b], f5[sx, blk, i ^ 1, c, a - d : b - d])
                    z0 = max(0, cz)  # nodes z whose upstream z - cz is inside
                    z1 = nz + min(0, cz)
                    for g in range(nrows):
                        if ga <= g < gb:
                            continue
                        sy = y0 + g - cy
                        row = gi[g * Lr : (g + 1) * Lr]
                        if sy < 0 or sy >= ny:
                            _fill(row, bi, B)
                            continue
                        o = (sy % G) * Lr
                        _copy(row[z0 * B : z1 * B], f5[sx, sy // G, i ^ 1, c, o + (z0 - cz) * B : o + (z1 - cz) * B])
                    if cz != 0:
                        e = 0 if cz > 0 else Lr - B  # the z-face nodes: upstream outside
                        for g in range(nrows):
                            _fill(gi[g * Lr + e : g * Lr + e + B], bi, B)
                if n > 0:
                    _collide_block_sym(gat, c, l0, n, 0, rexp, has, Q, EO, pw, x, blk, pexp, cE, cO, B == 1, use_src)
                # scatter post_i(r) into slot (r + c_i, i); dropped where r + c_i is outside the grid
                for i in range(nq):
                    tx = x + _CX[i]
                    if tx < 0 or tx >= nx:
                        continue
                    cy = _CY[i]
                    cz = _CZ[i]
                    bi = binf[i]
                    p = i >> 1
                    ep = EO[p * SYM_RUN : p * SYM_RUN + n]
                    op = EO[(NH + p) * SYM_RUN : (NH + p) * SYM_RUN + n]
                    sg = sgn[i & 1]
                    s = gat[i, c]
                    T = f5[tx, blk, i, c]
                    ga = max(0, -cy)  # rows whose target row is in this block
                    gb = min(nrows, nrows - cy)
                    if gb > ga:
                        d = cy * Lr + cz * B  # s[l] -> T[l + d]
                        a = max(ga * Lr, -d)
                        b = min(gb * Lr, R - d)
                        _put(T, s, d, a, b, l0, l1, ep, op, sg, zero)
                        if cz != 0:  # the z-face nodes' values landed on inflow slots of the next (previous) row
                            e = (nz - 1) * B if cz > 0 else 0
                            for g in range(ga, gb):
                                t = g * Lr + e
                                if t >= a and t + B <= b:
                                    _fill(T[t + d : t + d + B], bi, B)
                    z0 = max(0, -cz)  # nodes z whose target z + cz is inside
                    z1 = nz - max(0, cz)
                    for g in range(nrows):
                        if ga <= g < gb:
                            continue
                        ty = y0 + g + cy
                        if ty < 0 or ty >= ny:
                            continue
                        d = (ty % G - g) * Lr + cz * B
                        _put(f5[tx, ty // G, i, c], s, d, g * Lr + z0 * B, g * Lr + z1 * B, l0, l1, ep, op, sg, zero)
