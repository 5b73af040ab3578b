"""The collision of the lattice-Boltzmann sweeps: the parity split of the moving block and its products (numba).

``_parity_blocks`` splits a moving block over the opposite pairs; ``_collide_pairs`` applies the halves to an
occupied run through ``_pair_product``; ``_symmetry_blocks`` and ``_collide_sym`` / ``_collide_run`` do the same
by the cube's symmetry (the in-place sweeps); ``_block_occupancy`` finds a block's occupied run and its densities
and ``_collide_block`` / ``_collide_block_sym`` collide it; ``_add_squares`` is the ||f||^2 of a measuring sweep.
The package docstring (``lighting.lb``, "Layout and kernel") describes where they run.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from foliage_tools.lighting.lb.lattice import DIRECTIONS, OPPOSITE
from foliage_tools.lighting.lb.directions import NAXIAL_PAIRS, NH, NQ
from foliage_tools.lighting.lb.storage import load


def _parity_blocks(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Even and odd parts (..., 9, 9) of moving blocks A (..., 18, 18) over the opposite pairs (2p, 2p + 1).

    With s_p = f_2p + f_2p+1 and d_p = f_2p - f_2p+1, ``(A f)_2p = (AE s + AO d)_p`` and
    ``(A f)_2p+1 = (AE s - AO d)_p``, where AE = (A[2p, 2q] + A[2p, 2q+1]) / 2 and
    AO = (A[2p, 2q] - A[2p, 2q+1]) / 2. This needs A to commute with inversion, which holds for
    every Omega of geist2008 eqs. (5)-(9) (it depends only on the angle between directions); a
    block that does not is refused rather than solved wrongly.
    """
    opp = np.asarray(OPPOSITE[1:]) - 1
    if not np.array_equal(opp, np.arange(NQ) ^ 1):
        raise AssertionError("lattice order changed: direction 2p + 1 must be the opposite of 2p")
    if not np.allclose(A[..., opp, :][..., :, opp], A, rtol=0, atol=1e-12 * max(1.0, float(np.abs(A).max()))):
        raise ValueError("the collision block does not commute with inversion c -> -c; the kernel's parity split needs it")
    even, odd = A[..., 0::2, 0::2], A[..., 0::2, 1::2]
    return (even + odd) / 2, (even - odd) / 2


@njit(fastmath=True, cache=True)
def _pair_product(M, S, E):  # pragma: no cover - compiled
    """E = M @ S for M (9, 9) and S, E (9, n): one half of the parity-split collision.

    Written out for three output rows per pass: their 27 coefficients stay in (AVX-512) registers
    and each load of s_q feeds three FMAs. One core, n = 1216 (64^3, 57 rhs), operands in cache:
    ~140 GFLOP/s against ~37 for BLAS gemm through np.dot (packing the operands of such thin
    products costs it more than the arithmetic) and ~95 for one output row per pass.
    """
    n = S.shape[1]
    s0 = S[0]
    s1 = S[1]
    s2 = S[2]
    s3 = S[3]
    s4 = S[4]
    s5 = S[5]
    s6 = S[6]
    s7 = S[7]
    s8 = S[8]
    for p in range(0, NH, 3):
        ea = E[p]
        eb = E[p + 1]
        ec = E[p + 2]
        a0, a1, a2, a3, a4, a5, a6, a7, a8 = M[p, 0], M[p, 1], M[p, 2], M[p, 3], M[p, 4], M[p, 5], M[p, 6], M[p, 7], M[p, 8]
        b0, b1, b2, b3, b4, b5, b6, b7, b8 = (
            M[p + 1, 0], M[p + 1, 1], M[p + 1, 2], M[p + 1, 3], M[p + 1, 4], M[p + 1, 5], M[p + 1, 6], M[p + 1, 7], M[p + 1, 8]
        )
        c0, c1, c2, c3, c4, c5, c6, c7, c8 = (
            M[p + 2, 0], M[p + 2, 1], M[p + 2, 2], M[p + 2, 3], M[p + 2, 4], M[p + 2, 5], M[p + 2, 6], M[p + 2, 7], M[p + 2, 8]
        )
        for l in range(n):
            v0, v1, v2, v3, v4, v5, v6, v7, v8 = s0[l], s1[l], s2[l], s3[l], s4[l], s5[l], s6[l], s7[l], s8[l]
            ea[l] = a0 * v0 + a1 * v1 + a2 * v2 + a3 * v3 + a4 * v4 + a5 * v5 + a6 * v6 + a7 * v7 + a8 * v8
            eb[l] = b0 * v0 + b1 * v1 + b2 * v2 + b3 * v3 + b4 * v4 + b5 * v5 + b6 * v6 + b7 * v7 + b8 * v8
            ec[l] = c0 * v0 + c1 * v1 + c2 * v2 + c3 * v3 + c4 * v4 + c5 * v5 + c6 * v6 + c7 * v7 + c8 * v8


@njit(fastmath=True, cache=True)
def _add_squares(F, q):  # pragma: no cover - compiled
    """q[c] += sum over directions i of F[i, c]^2 (F (18, C, run), q (C, run) float64): mode 1's ||f||^2."""
    for i in range(F.shape[0]):
        for c in range(F.shape[1]):
            fi = F[i, c]
            qc = q[c]
            for l in range(fi.size):
                v = load(fi[l])
                qc[l] += v * v


@njit(fastmath=True, cache=True)
def _add_source(ep, op, p, c, l0, n, has, pexp, p0, cE, cO, one):  # pragma: no cover - compiled
    """ep += cE[m, c, p] pexp[m, c, p0 : p0 + n] and op += cO[...] likewise over the materials m with has[m]: the
    beams' first-collision source of pair p split into its even and odd parts (``_collide_pairs``); ``one``: the
    coefficients are constant along the run (a single right-hand side), else taken at [l0, l0 + n)."""
    for m in range(has.size):
        if not has[m]:
            continue
        pm = pexp[m, c, p0 : p0 + n]
        if one:
            ce1 = cE[m, c, p, 0]
            co1 = cO[m, c, p, 0]
            for l in range(n):
                v = pm[l]
                ep[l] += ce1 * v
                op[l] += co1 * v
        else:
            ce = cE[m, c, p, l0 : l0 + n]
            co = cO[m, c, p, l0 : l0 + n]
            for l in range(n):
                v = pm[l]
                ep[l] += ce[l] * v
                op[l] += co[l] * v


@njit(fastmath=True, cache=True)
def _collide_pairs(F, c, l0, n, rexp, r0, has, AE, AO, ae, ao, Sb, Db, Eb, Ob, extra, pexp, p0, cE, cO, one, use_src):  # pragma: no cover - compiled
    """E = AE S and O = AO D for channel c of the run [l0, l0 + n) of F (18, C, run), summed over materials.

    Omega depends only on the angle between directions, so it commutes with inversion c -> -c; over
    the opposite pairs (2p, 2p + 1) it splits into an even part acting on s = f_2p + f_2p+1 and an
    odd part acting on d = f_2p - f_2p+1 (``_parity_blocks``): two (9 x 9) @ (9 x n) products
    (``_pair_product``), half the multiply-adds of (18 x 18) @ (18 x n). The step density is folded
    into S = rho_p s and D = rho_p d (``rexp[m, k, r0 : r0 + n]``: rho_p on material m's nodes, 0
    elsewhere; k = 0 for the axial pairs p < 3, 1 for the non-axial ones, which have their own
    rho_d on the ``ordinates`` lattice), so geist2008 eq. (2) (f_0 removed, sec. 3) is f_2p + E_p +
    O_p and f_2p+1 + E_p - O_p, added by the caller on the way into the target slots. Materials
    have disjoint nodes, so their products add up. ``use_src``: the first-collision source of the
    beams is added too, s_i = coef_i(m, k) power(node, k), split the same way: ``pexp[m, c, p0 : p0 +
    n]`` is the power on material m's nodes (0 elsewhere; with one material the power itself),
    ``cE``, ``cO`` (nmat, C, 9, run) the parity parts of the coefficients tiled along the run
    (``_Operator``); ``one``: a single right-hand side, whose coefficients are constant along it.
    ``ae``, ``ao``: thread-local (9, 9) scratch; ``Sb, Db, Eb, Ob`` (9, n), ``extra`` >= 18 n values.
    """
    first = True
    for m in range(AE.shape[0]):
        if not has[m]:
            continue
        for p in range(NH):
            for q in range(NH):
                ae[p, q] = AE[m, c, p, q]
                ao[p, q] = AO[m, c, p, q]
        for p in range(NH):
            re = rexp[m, 0 if p < NAXIAL_PAIRS else 1, r0 : r0 + n]
            fa = F[2 * p, c, l0 : l0 + n]
            fb = F[2 * p + 1, c, l0 : l0 + n]
            sp = Sb[p]
            dp = Db[p]
            for l in range(n):
                r = re[l]
                va = load(fa[l])
                vb = load(fb[l])
                sp[l] = r * (va + vb)
                dp[l] = r * (va - vb)
        if first:
            _pair_product(ae, Sb, Eb)
            _pair_product(ao, Db, Ob)
            first = False
        else:
            # a further material: add its products (adding inside _pair_product instead ran 2x slower)
            Tb = extra[: 2 * NH * n].reshape((2 * NH, n))
            _pair_product(ae, Sb, Tb[:NH])
            _pair_product(ao, Db, Tb[NH:])
            for p in range(NH):
                ep = Eb[p]
                op = Ob[p]
                tp = Tb[p]
                tq = Tb[NH + p]
                for l in range(n):
                    ep[l] += tp[l]
                    op[l] += tq[l]
    if use_src:
        for p in range(NH):
            _add_source(Eb[p], Ob[p], p, c, l0, n, has, pexp, p0, cE, cO, one)


def _symmetry_bases() -> tuple[np.ndarray, np.ndarray]:
    """Rows (9, 9) of the symmetry-adapted coordinates of the even (pair sums) and odd (pair differences) sectors.

    A moving block depends only on the angle between directions (and on whether each is axial or not), so it
    commutes with the 48 symmetries of the cube, which permute the 3 axial and the 6 non-axial pair axes. By
    Schur's lemma it is then block-diagonal in coordinates that transform as the irreducible representations:
    polynomials in the pair's direction v_p = c_2p evaluated over each set (``_collide_sym`` hard-codes these
    rows). Even sector, functions of the unoriented axis: 1 (A1) on each set, x^2 - y^2 and 2z^2 - x^2 - y^2
    (E) on each set, xy, yz, zx (T2, non-axial only). Odd sector, oriented: x, y, z (T1) on each set and
    x(y^2 - z^2), y(z^2 - x^2), z(x^2 - y^2) (T2, non-axial only). Entries are 0, +-1, +-2.
    """
    v = np.asarray(DIRECTIONS[1::2][:NH], dtype=np.float64)  # c_2p
    x, y, z = v.T
    ax = (np.abs(v).sum(axis=1) == 1).astype(np.float64)
    dg = 1.0 - ax
    even = [ax, dg, ax * (x * x - y * y), dg * (x * x - y * y), ax * (2 * z * z - x * x - y * y), dg * (2 * z * z - x * x - y * y),
            dg * x * y, dg * y * z, dg * z * x]
    odd = [ax * x, ax * y, ax * z, dg * x, dg * y, dg * z, dg * x * (y * y - z * z), dg * y * (z * z - x * x), dg * z * (x * x - y * y)]
    return np.array(even), np.array(odd)


#: The (row, column) pairs of the blocks ``_symmetry_blocks`` packs, in order: even sector A1, E (x^2 - y^2),
#: E (2z^2 - x^2 - y^2) as 2 x 2 blocks of (axial, non-axial) and T2 as its diagonal; odd sector T1 (x, y, z) as
#: 2 x 2 blocks of (axial, non-axial) and T2 as its diagonal.
_EVEN_SLOTS = ((0, 0), (0, 1), (1, 0), (1, 1), (2, 2), (2, 3), (3, 2), (3, 3), (4, 4), (4, 5), (5, 4), (5, 5), (6, 6), (7, 7), (8, 8))
_ODD_SLOTS = ((0, 0), (0, 3), (3, 0), (3, 3), (1, 1), (1, 4), (4, 1), (4, 4), (2, 2), (2, 5), (5, 2), (5, 5), (6, 6), (7, 7), (8, 8))


def _symmetry_blocks(AE: np.ndarray, AO: np.ndarray) -> np.ndarray:
    """The 30 coefficients (..., 30) of the parity blocks AE, AO (..., 9, 9) in symmetry-adapted coordinates.

    With W the rows of ``_symmetry_bases`` (orthogonal, D = W W^T diagonal), A = W^T N W for N = D^-1 W A W^T D^-1,
    and N has nonzeros only at ``_EVEN_SLOTS`` / ``_ODD_SLOTS``: 15 multiply-adds per sector where A has 81
    (``_collide_sym``). A block that is not of that form is refused (as ``_parity_blocks`` refuses one that does
    not commute with inversion) rather than collided wrongly.
    """
    out = []
    for W, A, slots in zip(_symmetry_bases(), (AE, AO), (_EVEN_SLOTS, _ODD_SLOTS)):
        dinv = 1.0 / np.diag(W @ W.T)
        N = np.einsum("i,ip,...pq,jq,j->...ij", dinv, W, A, W, dinv)
        keep = np.zeros((NH, NH), bool)
        keep[tuple(np.array(slots).T)] = True
        scale = max(1.0, float(np.abs(A).max()))
        if np.abs(N[..., ~keep]).max(initial=0.0) > 1e-12 * scale:
            raise ValueError("the collision block does not have the lattice's cubic symmetry; the kernel's symmetry "
                             "blocks need it")
        out.append(np.stack([N[..., i, j] for i, j in slots], axis=-1))
    return np.concatenate(out, axis=-1)


#: The longest run ``_collide_sym`` takes: a block of ``layout._BLOCK_VALUES`` values.
SYM_MAX_RUN = 4096


def sym_row_stride(run: int) -> int:
    """A row distance (values) >= run for scratch rows read together: a multiple of 1024 values plus 16, so that 18
    rows fall in different L1 sets (rows 16 KiB apart all map to one set: a copy of 18 such rows ran 3-4x slower)."""
    return -(-run // 1024) * 1024 + 16


#: Distance between the output rows of ``_collide_sym`` in its scratch array (``sym_row_stride`` of the longest
#: run), a compile-time constant: with row distances known only at run time the vectorizer gave up on the loop's
#: many possible overlaps and it ran scalar.
SYM_RUN = sym_row_stride(SYM_MAX_RUN)


@njit(fastmath=True, cache=True)
def _collide_sym(F, c, l0, n, rexp, r0, m, Q, EO):  # pragma: no cover - compiled
    """E = AE S and O = AO D (``_collide_pairs``) of material m in symmetry-adapted coordinates, in one pass.

    For channel c of the run [l0, l0 + n) of F (18, C, run) (n <= ``SYM_MAX_RUN``): S_p = rho_p (f_2p + f_2p+1), D_p =
    rho_p (f_2p - f_2p+1) (rho_p = rexp[m, 0 | 1, r0 + l], axial | non-axial, 0 off m's nodes), transformed by the
    rows W of ``_symmetry_bases`` (additions), multiplied by the blocks Q[m, c] of ``_symmetry_blocks`` (30
    multiply-adds where the (9 x 9) products take 162) and transformed back by W^T. E_p is written to
    EO[p SYM_RUN + l], O_p to EO[(9 + p) SYM_RUN + l]; the post-collision values are f_2p + E_p + O_p and
    f_2p+1 + E_p - O_p. F's rows should not be a multiple of 1024 values apart (``sym_row_stride``): 18 rows in
    one L1 set run several times slower.
    """
    q = Q[m, c]
    a00, a01, a10, a11 = q[0], q[1], q[2], q[3]
    b00, b01, b10, b11 = q[4], q[5], q[6], q[7]
    c00, c01, c10, c11 = q[8], q[9], q[10], q[11]
    t6, t7, t8 = q[12], q[13], q[14]
    x00, x01, x10, x11 = q[15], q[16], q[17], q[18]
    y00, y01, y10, y11 = q[19], q[20], q[21], q[22]
    z00, z01, z10, z11 = q[23], q[24], q[25], q[26]
    u6, u7, u8 = q[27], q[28], q[29]
    u0 = np.uint64(l0)
    v0_ = np.uint64(r0)
    for l in range(np.uint64(n)):
        # every array indexed in full (one base pointer each: slices per direction would give the vectorizer more
        # possible overlaps to check than it takes), by unsigned indices (no negative-index wraparound): or the
        # loop stays scalar, ~9x slower
        ka = rexp[m, 0, v0_ + l]
        kd = rexp[m, 1, v0_ + l]
        j = u0 + l
        v0, v1, v2, v3, v4, v5 = load(F[0, c, j]), load(F[1, c, j]), load(F[2, c, j]), load(F[3, c, j]), load(F[4, c, j]), load(F[5, c, j])
        v6, v7, v8, v9, v10, v11 = load(F[6, c, j]), load(F[7, c, j]), load(F[8, c, j]), load(F[9, c, j]), load(F[10, c, j]), load(F[11, c, j])
        v12, v13, v14, v15, v16, v17 = (load(F[12, c, j]), load(F[13, c, j]), load(F[14, c, j]), load(F[15, c, j]), load(F[16, c, j]),
                                        load(F[17, c, j]))
        s0, s1, s2 = v0 + v1, v2 + v3, v4 + v5
        s3, s4, s5, s6, s7, s8 = v6 + v7, v8 + v9, v10 + v11, v12 + v13, v14 + v15, v16 + v17
        d0, d1, d2 = v0 - v1, v2 - v3, v4 - v5
        d3, d4, d5, d6, d7, d8 = v6 - v7, v8 - v9, v10 - v11, v12 - v13, v14 - v15, v16 - v17
        # even sector: W s (rows of ``_symmetry_bases``), axial rows x rho_a, non-axial x rho_d
        pxy = s3 + s4
        pxz = s5 + s6
        pyz = s7 + s8
        w0 = ka * (s0 + s1 + s2)
        w1 = kd * (pxy + pxz + pyz)
        w2 = ka * (s0 - s1)
        w3 = kd * (pxz - pyz)
        w4 = ka * (s2 + s2 - s0 - s1)
        w5 = kd * (pxz + pyz - pxy - pxy)
        w6 = kd * (s3 - s4)
        w7 = kd * (s7 - s8)
        w8 = kd * (s5 - s6)
        g0 = a00 * w0 + a01 * w1
        g1 = a10 * w0 + a11 * w1
        g2 = b00 * w2 + b01 * w3
        g3 = b10 * w2 + b11 * w3
        g4 = c00 * w4 + c01 * w5
        g5 = c10 * w4 + c11 * w5
        g6 = t6 * w6
        g7 = t7 * w7
        g8 = t8 * w8
        # back: W^T g
        h1 = g1 - g5 - g5
        h2 = g1 + g3 + g5
        h3 = g1 - g3 + g5
        E0 = g0 + g2 - g4
        E1 = g0 - g2 - g4
        E2 = g0 + g4 + g4
        E3 = h1 + g6
        E4 = h1 - g6
        E5 = h2 + g8
        E6 = h2 - g8
        E7 = h3 + g7
        E8 = h3 - g7
        # odd sector
        ex = d3 + d4
        ey = d5 + d6
        w0 = ka * d0
        w1 = ka * d1
        w2 = ka * d2
        w3 = kd * (ex + ey)
        w4 = kd * (d3 - d4 + d7 + d8)
        w5 = kd * (d5 - d6 + d7 - d8)
        w6 = kd * (ex - ey)
        w7 = kd * (d4 - d3 + d7 + d8)
        w8 = kd * (d5 - d6 - d7 + d8)
        g0 = x00 * w0 + x01 * w3
        g3 = x10 * w0 + x11 * w3
        g1 = y00 * w1 + y01 * w4
        g4 = y10 * w1 + y11 * w4
        g2 = z00 * w2 + z01 * w5
        g5 = z10 * w2 + z11 * w5
        g6 = u6 * w6
        g7 = u7 * w7
        g8 = u8 * w8
        O3 = g3 + g4 + g6 - g7
        O4 = g3 - g4 + g6 + g7
        O5 = g3 + g5 - g6 + g8
        O6 = g3 - g5 - g6 - g8
        O7 = g4 + g5 + g7 - g8
        O8 = g4 - g5 + g7 + g8
        O0 = g0
        O1 = g1
        O2 = g2
        EO[0 * SYM_RUN + l] = E0
        EO[1 * SYM_RUN + l] = E1
        EO[2 * SYM_RUN + l] = E2
        EO[3 * SYM_RUN + l] = E3
        EO[4 * SYM_RUN + l] = E4
        EO[5 * SYM_RUN + l] = E5
        EO[6 * SYM_RUN + l] = E6
        EO[7 * SYM_RUN + l] = E7
        EO[8 * SYM_RUN + l] = E8
        EO[9 * SYM_RUN + l] = O0
        EO[10 * SYM_RUN + l] = O1
        EO[11 * SYM_RUN + l] = O2
        EO[12 * SYM_RUN + l] = O3
        EO[13 * SYM_RUN + l] = O4
        EO[14 * SYM_RUN + l] = O5
        EO[15 * SYM_RUN + l] = O6
        EO[16 * SYM_RUN + l] = O7
        EO[17 * SYM_RUN + l] = O8


@njit(fastmath=True, cache=True)
def _collide_run(F, c, l0, n, rexp, r0, has, Q, EO, pexp, p0, cE, cO, one, use_src):  # pragma: no cover - compiled
    """``_collide_pairs`` by ``_collide_sym``: E_p and O_p of channel c of the run [l0, l0 + n) of F summed over
    the materials with has[m] (disjoint nodes), plus with ``use_src`` the beams' source (``_add_source``), in rows
    p and 9 + p of EO (``SYM_RUN`` apart; rows 18-35 are scratch for a second material)."""
    first = True
    for m in range(has.size):
        if not has[m]:
            continue
        _collide_sym(F, c, l0, n, rexp, r0, m, Q, EO if first else EO[NQ * SYM_RUN :])
        if not first:
            for p in range(NQ):
                dst = EO[p * SYM_RUN : p * SYM_RUN + n]
                src = EO[(NQ + p) * SYM_RUN : (NQ + p) * SYM_RUN + n]
                for l in range(n):
                    dst[l] += src[l]
        first = False
    if use_src:
        for p in range(NH):
            _add_source(EO[p * SYM_RUN : p * SYM_RUN + n], EO[(NH + p) * SYM_RUN : (NH + p) * SYM_RUN + n], p, c, l0, n, has,
                        pexp, p0, cE, cO, one)


@njit(fastmath=True, cache=True)
def _block_occupancy(rho, rhod, mat, pw, x, blk, G, B, add_src, rexp, pexp, has):  # pragma: no cover - compiled
    """The occupied run [l0, l1) (flat values: row g, node z, rhs k at (g nz + z) B + k) of block (x, blk) of the
    block layout, l0 = l1 = 0 if no node is occupied; per material m, has[m] whether m has an occupied node,
    rexp[m, 0 | 1, : l1 - l0] the axial | non-axial step density on m's nodes (0 elsewhere) and, with ``add_src``
    and more than one material, pexp[m, c, : l1 - l0] the beams' power pw[x, blk, c] on m's nodes."""
    ny = rho.shape[1]
    nz = rho.shape[2]
    nmat = has.size
    C = pexp.shape[1]
    y0 = blk * G
    nrows = min(G, ny - y0)
    j0 = -1
    j1 = -1
    for m in range(nmat):
        has[m] = False
    for g in range(nrows):
        rr = rho[x, y0 + g]
        mm = mat[x, y0 + g]
        for z in range(nz):
            if rr[z] > 0:
                if j0 < 0:
                    j0 = g * nz + z
                j1 = g * nz + z + 1
                has[mm[z]] = True
    if j1 < 0:
        return 0, 0
    for m in range(nmat):
        re = rexp[m, 0]
        rq = rexp[m, 1]
        for j in range(j0, j1):
            g = j // nz
            z = j - g * nz
            own = mat[x, y0 + g, z] == m
            v = rho[x, y0 + g, z] if own else 0.0
            vd = rhod[x, y0 + g, z] if own else 0.0
            for b in range(B):
                re[(j - j0) * B + b] = v
                rq[(j - j0) * B + b] = vd
            if add_src and nmat > 1:
                for cc in range(C):
                    for b in range(B):
                        pexp[m, cc, (j - j0) * B + b] = pw[x, blk, cc, j * B + b] if own else 0.0
    return j0 * B, j1 * B


@njit(fastmath=True, cache=True)
def _collide_block(F, c, la, n, ra, rexp, has, AE, AO, ae, ao, Sb, Db, Eb, Ob, extra, pw, x, blk, pexp, cE, cO, one, add_src):  # pragma: no cover - compiled
    """``_collide_pairs`` for channel c of the run [la, la + n) of a block, inside its occupied run: ra = la - l0 is
    the offset into the densities ``_block_occupancy`` expanded from l0 (the beams' power: pw[x, blk] itself, at
    la, with one material, else pexp at ra)."""
    if AE.shape[0] == 1:
        _collide_pairs(F, c, la, n, rexp, ra, has, AE, AO, ae, ao, Sb, Db, Eb, Ob, extra, pw[x, blk : blk + 1], la, cE, cO,
                       one, add_src)
    else:
        _collide_pairs(F, c, la, n, rexp, ra, has, AE, AO, ae, ao, Sb, Db, Eb, Ob, extra, pexp, ra, cE, cO, one, add_src)


@njit(fastmath=True, cache=True)
def _collide_block_sym(F, c, la, n, ra, rexp, has, Q, EO, pw, x, blk, pexp, cE, cO, one, add_src):  # pragma: no cover - compiled
    """``_collide_block`` by the symmetry blocks Q (``_collide_run``): E_p, O_p in rows p, 9 + p of EO."""
    if has.size == 1:
        _collide_run(F, c, la, n, rexp, ra, has, Q, EO, pw[x, blk : blk + 1], la, cE, cO, one, add_src)
    else:
        _collide_run(F, c, la, n, rexp, ra, has, Q, EO, pexp, ra, cE, cO, one, add_src)
