"""The collision of the lattice-Boltzmann sweeps: the parity split of the moving block and its products (numba).

``_parity_blocks`` splits a moving block over the opposite pairs; ``_collide_pairs`` applies the halves to an
occupied run through ``_pair_product``; ``_add_squares`` is the ||f||^2 of a measuring sweep. The package
docstring (``lighting.lb``, "Layout and kernel") describes where they run.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from foliage_tools.lighting.lattice import OPPOSITE
from foliage_tools.lighting.lb.directions import NAXIAL_PAIRS, NH, NQ
from foliage_tools.lighting.storage import load


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
        for m in range(AE.shape[0]):
            if not has[m]:
                continue
            pm = pexp[m, c, p0 : p0 + n]
            for p in range(NH):
                ep = Eb[p]
                op = Ob[p]
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
