"""The fused collision + push-streaming sweeps of the lattice-Boltzmann solver (numba).

``_sweep_rows`` sweeps long rows (many right-hand sides) one at a time, ``_sweep_blocks`` blocks of short rows;
``_Operator`` (``layout``) picks one. The package docstring (``lighting.lb``, "Layout and kernel") describes both.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from foliage_tools.lighting.lb.directions import _CX, _CY, _CZ, NAXIAL_PAIRS, NH
from foliage_tools.lighting.lb.kernels_collide import _add_squares, _block_occupancy, _collide_block, _collide_pairs
from foliage_tools.lighting.lb.kernels_stream import _stream_piece, _stream_segment
from foliage_tools.lighting.lb.storage import convert, load

#: ``_sweep_rows``: occupied runs at least this long collide by the parity-split products, shorter ones by the hand loop.
_LONG_RUN_MIN = 256


@njit(parallel=True, fastmath=True, cache=True)
def _sweep_rows(f, out, rho, rhod, mat, A, AE, AO, mode, wt, part1, part2, pw, ct, cE, cO, use_src):  # pragma: no cover - compiled
    """One fused collision + push-streaming sweep over rows of nz * B values (long: many right-hand sides).

    Writes every non-inflow slot of ``out``. The layout of ``_Operator`` with one row per block (G = 1):
    f, out, wt : (nx, ny, 18, C, nz, B); rho, rhod : (nx, ny, nz) step density of the axial and the
    non-axial directions; mat : (nx, ny, nz) uint8;
    A : (nmat, C, 18, 18) moving block of the collision (A[m, c, i, j], ``collision.unit_moving_block``);
    AE, AO : (nmat, C, 9, 9) its even and odd parts over opposite pairs (``_parity_blocks``);
    part1, part2 : (nx, C, nz*B) float64 partial sums, per x-slab and (z, b).

    mode 0: out = T f.
    mode 1: out = T f, part1 += (out - f)^2 and part2 += f^2 (the residual of a plain sweep).
    mode 2: out = f - T f (the BiCGSTAB operator I - T), part1 += wt * out, part2 += out^2.
    ``use_src`` (modes 0 and 1 only): the beams' first-collision source is added (``_collide_pairs``;
    pw (nx, ny, C, nz*B) the power per node, ct (nmat, C, 18, nz*B) the coefficients, cE, cO their
    parity parts), so T f becomes the affine sweep T f + S s of a problem with a volume source.
    """
    nx, ny, nq, C, nz, B = f.shape
    nmat = A.shape[0]
    L = nz * B
    add_src = use_src and mode != 2
    # (x, y, direction, channel) -> the row's run of nz * B values, viewed once here: building these
    # views per row and direction (reshape, then index) cost ~1.1x on short rows (64^3, 1 rhs)
    f5 = f.reshape((nx, ny, nq, C, L))
    out5 = out.reshape((nx, ny, nq, C, L))
    wt5 = wt.reshape((nx, ny, nq, C, L))
    for x in prange(nx):
        # arithmetic in rho's dtype (float32 for both storages, ``lighting.storage``); H holds stored values
        H = np.empty((nq, C, L), dtype=f.dtype)
        buf = np.empty(nq * L, dtype=rho.dtype)
        prod = np.empty(nq * L, dtype=rho.dtype)
        extra = np.empty(nq * L, dtype=rho.dtype)
        acc = np.empty((3, L), dtype=rho.dtype)
        rexp = np.empty((nmat, 2, L), dtype=rho.dtype)
        pexp = np.zeros((nmat, C, L if add_src and nmat > 1 else 1), dtype=rho.dtype)
        has = np.zeros(nmat, dtype=np.bool_)
        ae = np.empty((NH, NH), dtype=rho.dtype)  # thread-local copies of AE[m, c], AO[m, c]
        ao = np.empty((NH, NH), dtype=rho.dtype)
        sgn = np.empty(2, dtype=rho.dtype)  # +1 / -1 in the field's dtype (a float64 sign would promote)
        sgn[0] = 1.0
        sgn[1] = -1.0
        for y in range(ny):
            rr = rho[x, y]
            rd = rhod[x, y]
            mm = mat[x, y]
            z0 = nz
            z1 = -1
            for m in range(nmat):
                has[m] = False
            for z in range(nz):
                if rr[z] > 0:
                    if z < z0:
                        z0 = z
                    z1 = z
                    has[mm[z]] = True
            F = f5[x, y]
            if mode == 1:
                _add_squares(F, part2[x])
            if z1 >= 0:
                # collision on the occupied z-range [z0, z1] of the row (zero-based views vectorize)
                l0 = z0 * B
                n = (z1 + 1 - z0) * B
                for m in range(nmat):
                    if has[m]:
                        re = rexp[m, 0, l0 : l0 + n]
                        rq = rexp[m, 1, l0 : l0 + n]
                        for zz in range(z1 + 1 - z0):
                            own = mm[z0 + zz] == m
                            v = rr[z0 + zz] if own else 0.0
                            vd = rd[z0 + zz] if own else 0.0
                            for b in range(B):
                                re[zz * B + b] = v
                                rq[zz * B + b] = vd
                        if add_src and nmat > 1:
                            for cc in range(C):
                                pm = pexp[m, cc, l0 : l0 + n]
                                pr = pw[x, y, cc, l0 : l0 + n]
                                for zz in range(z1 + 1 - z0):
                                    own = mm[z0 + zz] == m
                                    for b in range(B):
                                        pm[zz * B + b] = pr[zz * B + b] if own else 0.0
                if n >= _LONG_RUN_MIN:
                    # long runs: the parity-split products (``_collide_pairs``), added to the streamed values
                    # on the way into the target slots: the post-collision row is never stored
                    Sb = buf[: NH * n].reshape((NH, n))
                    Db = buf[NH * n : 2 * NH * n].reshape((NH, n))
                    Eb = prod[: NH * n].reshape((NH, n))
                    Ob = prod[NH * n : 2 * NH * n].reshape((NH, n))
                    for c in range(C):
                        if nmat == 1:
                            _collide_pairs(F, c, l0, n, rexp, l0, has, AE, AO, ae, ao, Sb, Db, Eb, Ob, extra, pw[x, y : y + 1],
                                           l0, cE, cO, B == 1, add_src)
                        else:
                            _collide_pairs(F, c, l0, n, rexp, l0, has, AE, AO, ae, ao, Sb, Db, Eb, Ob, extra, pexp, l0, cE, cO,
                                           B == 1, add_src)
                        # push-streaming f_i(r + c_i) = post_i(r), z-shift an offset in the row; the source
                        # run [lo, hi) splits into the pass-through head [lo, l0), the collided run
                        # [l0, l0 + n) and the pass-through tail [l0 + n, hi)
                        for i in range(nq):
                            tx = x + _CX[i]
                            ty = y + _CY[i]
                            if tx < 0 or tx >= nx or ty < 0 or ty >= ny:
                                continue  # the light leaves the grid
                            dz = _CZ[i]
                            lo = (-dz if dz < 0 else 0) * B
                            hi = (nz - dz if dz > 0 else nz) * B
                            d = dz * B
                            o = out5[tx, ty, i, c]
                            s = F[i, c]
                            p = i >> 1
                            ep = Eb[p]
                            op = Ob[p]
                            sg = sgn[i & 1]
                            if mode == 0:
                                # a plain sweep builds only the views it uses (1.2x at 64^3, 57 rhs)
                                a = lo
                                b1 = min(hi, l0)
                                if b1 > a:
                                    o[a + d : b1 + d] = s[a:b1]
                                a = max(lo, l0)
                                b1 = min(hi, l0 + n)
                                if b1 > a:
                                    oo = o[a + d : b1 + d]
                                    ss = s[a:b1]
                                    ee = ep[a - l0 : b1 - l0]
                                    od = op[a - l0 : b1 - l0]
                                    for l in range(b1 - a):
                                        oo[l] = convert(load(ss[l]) + ee[l] + sg * od[l], oo)
                                a = max(lo, l0 + n)
                                b1 = hi
                                if b1 > a:
                                    o[a + d : b1 + d] = s[a:b1]
                                continue
                            fo = f5[tx, ty, i, c]
                            wo = wt5[tx, ty, i, c]
                            q1 = part1[x, c]
                            q2 = part2[x, c]
                            a = lo
                            b1 = min(hi, l0)
                            if b1 > a:
                                _stream_piece(mode, True, o[a + d : b1 + d], s[a:b1], s[:0], s[:0], sg, fo[a + d : b1 + d],
                                              wo[a + d : b1 + d], q1[a + d : b1 + d], q2[a + d : b1 + d])
                            a = max(lo, l0)
                            b1 = min(hi, l0 + n)
                            if b1 > a:
                                _stream_piece(mode, True, o[a + d : b1 + d], s[a:b1], ep[a - l0 : b1 - l0],
                                              op[a - l0 : b1 - l0], sg, fo[a + d : b1 + d], wo[a + d : b1 + d],
                                              q1[a + d : b1 + d], q2[a + d : b1 + d])
                            a = max(lo, l0 + n)
                            b1 = hi
                            if b1 > a:
                                _stream_piece(mode, True, o[a + d : b1 + d], s[a:b1], s[:0], s[:0], sg, fo[a + d : b1 + d],
                                              wo[a + d : b1 + d], q1[a + d : b1 + d], q2[a + d : b1 + d])
                    continue  # streamed above
                else:
                    # short runs (the long-run path's per-call costs eat its gain: about even at n = 128,
                    # 1.2-1.7x slower at n = 64): three output directions per pass share each load of f_j
                    # (18 = 6 x 3)
                    a0 = acc[0, :n]
                    a1 = acc[1, :n]
                    a2 = acc[2, :n]
                    sc = buf[: nq * n].reshape((nq, n))  # rho_j f_j of one material and channel
                    for c in range(C):
                        for i in range(nq):
                            h = H[i, c]
                            fi = F[i, c]
                            for l in range(L):
                                h[l] = fi[l]
                        for m in range(nmat):
                            if not has[m]:
                                continue
                            for j in range(nq):
                                rj = rexp[m, 0 if j < 2 * NAXIAL_PAIRS else 1, l0 : l0 + n]
                                fj = F[j, c, l0 : l0 + n]
                                sj = sc[j]
                                for l in range(n):
                                    sj[l] = rj[l] * load(fj[l])
                            for i in range(0, nq, 3):
                                for l in range(n):
                                    a0[l] = 0.0
                                    a1[l] = 0.0
                                    a2[l] = 0.0
                                for j in range(nq):
                                    c0 = A[m, c, i, j]
                                    c1 = A[m, c, i + 1, j]
                                    c2 = A[m, c, i + 2, j]
                                    sj = sc[j]
                                    for l in range(n):
                                        v = sj[l]
                                        a0[l] += c0 * v
                                        a1[l] += c1 * v
                                        a2[l] += c2 * v
                                h0 = H[i, c, l0 : l0 + n]
                                h1 = H[i + 1, c, l0 : l0 + n]
                                h2 = H[i + 2, c, l0 : l0 + n]
                                # geist2008 eq. (2): f + sum_j A_ij rho_j f_j, f_0 removed (sec. 3)
                                for l in range(n):
                                    h0[l] = convert(load(h0[l]) + a0[l], h0)
                                    h1[l] = convert(load(h1[l]) + a1[l], h1)
                                    h2[l] = convert(load(h2[l]) + a2[l], h2)
                            if add_src:
                                pm = pexp[m, c, l0 : l0 + n] if nmat > 1 else pw[x, y, c, l0 : l0 + n]
                                for i in range(nq):
                                    h = H[i, c, l0 : l0 + n]
                                    ci = ct[m, c, i, l0 : l0 + n]
                                    for l in range(n):
                                        h[l] = convert(load(h[l]) + ci[l] * pm[l], h)
                src = H
            else:
                src = F  # empty row: pass-through
            # push-streaming: f_i(r + c_i) = post_i(r); z-shift is an offset in the row. The loops repeat
            # _stream_piece's on purpose: calling it per (direction, channel) here made short rows 1.25x slower
            for i in range(nq):
                tx = x + _CX[i]
                ty = y + _CY[i]
                dz = _CZ[i]
                if tx < 0 or tx >= nx or ty < 0 or ty >= ny:
                    continue
                lo = (-dz if dz < 0 else 0) * B
                hi = (nz - dz if dz > 0 else nz) * B
                d = dz * B
                n2 = hi - lo
                O = out5[tx, ty, i]
                if mode == 1:
                    Fo = f5[tx, ty, i]
                    for c in range(C):
                        o = O[c, lo + d : hi + d]
                        s = src[i, c, lo:hi]
                        fo = Fo[c, lo + d : hi + d]
                        rn = part1[x, c, lo + d : hi + d]
                        for l in range(n2):
                            v = s[l]
                            dd = load(v) - load(fo[l])
                            rn[l] += dd * dd
                            o[l] = v
                elif mode == 2:
                    Fo = f5[tx, ty, i]
                    Wo = wt5[tx, ty, i]
                    for c in range(C):
                        o = O[c, lo + d : hi + d]
                        s = src[i, c, lo:hi]
                        fo = Fo[c, lo + d : hi + d]
                        wo = Wo[c, lo + d : hi + d]
                        q1 = part1[x, c, lo + d : hi + d]
                        q2 = part2[x, c, lo + d : hi + d]
                        for l in range(n2):
                            w = load(fo[l]) - load(s[l])
                            o[l] = convert(w, o)
                            q1[l] += load(wo[l]) * w
                            q2[l] += w * w
                else:
                    for c in range(C):
                        o = O[c, lo + d : hi + d]
                        s = src[i, c, lo:hi]
                        for l in range(n2):
                            o[l] = s[l]


@njit(parallel=True, fastmath=True, cache=True)
def _sweep_blocks(f, out, rho, rhod, mat, AE, AO, mode, wt, part1, part2, pw, cE, cO, use_src):  # pragma: no cover - compiled
    """One fused collision + push-streaming sweep over blocks of G rows (short rows: few right-hand sides).

    Writes every non-inflow slot of ``out``. f, out, wt : (nx, NB, 18, C, G*nz, K), the block layout of ``_Operator``;
    rho, rhod : (nx, ny, nz) step density of the axial and the non-axial directions;
    mat : (nx, ny, nz) uint8; AE, AO : (nmat, C, 9, 9) the even and odd parts over opposite pairs of
    the unit-density moving block of Omega (``_parity_blocks``); part1, part2 : (nx, C, G*nz*K)
    float64 partial sums, per x-slab and position in the block's run.

    mode 0: out = T f.
    mode 1: out = T f, part1 += (out - f)^2 and part2 += f^2 (the residual of a plain sweep).
    mode 2: out = f - T f (the BiCGSTAB operator I - T), part1 += wt * out, part2 += out^2.
    ``use_src`` (modes 0 and 1 only): the beams' first-collision source is added (pw (nx, NB, C, G*nz*K)
    the power per node, cE, cO (nmat, C, 9, G*nz*K) the coefficients' parity parts; ``_collide_pairs``).
    """
    nx, nb, nq, C, gnz, B = f.shape
    ny = rho.shape[1]
    nz = rho.shape[2]
    G = gnz // nz
    Lr = nz * B  # one row's run
    R = G * Lr  # one block's run
    nmat = AE.shape[0]
    add_src = use_src and mode != 2
    f5 = f.reshape((nx, nb, nq, C, R))
    out5 = out.reshape((nx, nb, nq, C, R))
    wt5 = wt.reshape((nx, nb, nq, C, R))
    for x in prange(nx):
        # arithmetic in rho's dtype (float32 for both storages, ``lighting.storage``); ``save`` holds stored values
        buf = np.empty(2 * NH * R, dtype=rho.dtype)
        prod = np.empty(2 * NH * R, dtype=rho.dtype)
        extra = np.empty(2 * NH * R, dtype=rho.dtype)
        rexp = np.empty((nmat, 2, R), dtype=rho.dtype)
        pexp = np.zeros((nmat, C, R if add_src and nmat > 1 else 1), dtype=rho.dtype)
        has = np.zeros(nmat, dtype=np.bool_)
        save = np.empty(G * B, dtype=f.dtype)
        slots = np.empty(G, dtype=np.int64)
        ae = np.empty((NH, NH), dtype=rho.dtype)  # thread-local copies of AE[m, c], AO[m, c]
        ao = np.empty((NH, NH), dtype=rho.dtype)
        sgn = np.empty(2, dtype=rho.dtype)  # +1 / -1 in the field's dtype (a float64 sign would promote)
        sgn[0] = 1.0
        sgn[1] = -1.0
        for blk in range(nb):
            y0 = blk * G
            nrows = min(G, ny - y0)
            F = f5[x, blk]
            if mode == 1:
                _add_squares(F, part2[x])
            # the occupied run [l0, l1) of the block: only its nodes collide
            l0, l1 = _block_occupancy(rho, rhod, mat, pw, x, blk, G, B, add_src, rexp, pexp, has)
            n = l1 - l0
            Sb = buf[: NH * n].reshape((NH, n))
            Db = buf[NH * n : 2 * NH * n].reshape((NH, n))
            Eb = prod[: NH * n].reshape((NH, n))
            Ob = prod[NH * n : 2 * NH * n].reshape((NH, n))
            for c in range(C):
                if n > 0:
                    _collide_block(F, c, l0, n, 0, rexp, has, AE, AO, ae, ao, Sb, Db, Eb, Ob, extra, pw, x, blk, pexp, cE, cO,
                                   B == 1, add_src)
                # push-streaming f_i(r + c_i) = post_i(r): within a block a y- and z-shift is one
                # offset of the flat run; the row that crosses into the next (previous) block goes there
                q1 = part1[x, c]
                q2 = part2[x, c]
                for i in range(nq):
                    tx = x + _CX[i]
                    if tx < 0 or tx >= nx:
                        continue  # the light leaves the grid
                    cy = _CY[i]
                    cz = _CZ[i]
                    wrap_z = -1 if cz == 0 else (nz - 1 if cz > 0 else 0)
                    s = F[i, c]
                    ep = Eb[i >> 1]
                    op = Ob[i >> 1]
                    sg = sgn[i & 1]
                    # rows whose target row is in this block
                    g0 = max(0, -cy)
                    g1 = min(nrows, nrows - cy)
                    if g1 > g0:
                        # a plain sweep passes s for the views it does not read (building them cost ~1.1x)
                        fo = f5[tx, blk, i, c] if mode != 0 else s
                        wo = wt5[tx, blk, i, c] if mode == 2 else s
                        _stream_segment(mode, out5[tx, blk, i, c], s, fo, wo, q1, q2, g0 * Lr, g1 * Lr,
                                        cy * Lr + cz * B, nrows * Lr, wrap_z, B, Lr, ep, op, sg, l0, l1, save, slots)
                    # the row whose target row is in the neighbouring block
                    tb = -1
                    if cy > 0 and nrows == G and blk + 1 < nb:
                        tb = blk + 1
                        a = (G - 1) * Lr
                        d = cz * B - (G - 1) * Lr
                        lim = min(G, ny - y0 - G) * Lr
                    elif cy < 0 and blk > 0:
                        tb = blk - 1
                        a = 0
                        d = (G - 1) * Lr + cz * B
                        lim = R
                    if tb >= 0:
                        fo = f5[tx, tb, i, c] if mode != 0 else s
                        wo = wt5[tx, tb, i, c] if mode == 2 else s
                        _stream_segment(mode, out5[tx, tb, i, c], s, fo, wo, q1, q2, a, a + Lr, d, lim, wrap_z, B, Lr,
                                        ep, op, sg, l0, l1, save, slots)
