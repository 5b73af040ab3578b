"""Lattice-Boltzmann kernels over whole fields in the block layout that are no sweep (numba).

The per-sweep energy balance (``_balance``), the once-scattered start of a beam (``_once_scattered``), the
never-scattered start, the energy density and a copy of a field (``_put_transmitted``, ``_field_energy``,
``_copy_field``: one parallel pass each, where numpy's float16 conversions and transposes took ~18 s of a 128^3
fp16 relightable solve), and the vector updates of BiCGSTAB and of extrapolation (``_dot``, ``_axpy_norm``,
``_update_xr``, ``_extrapolate``, ``_p_update``).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from foliage_tools.lighting.lb.directions import _CX, _CY, _CZ, NAXIAL_PAIRS, NQ
from foliage_tools.lighting.lb.storage import convert, load


@njit(parallel=True, cache=True)
def _balance(f, rho, rhod, mat, A, sig_a, inflow_mask, wq, pw, cq, use_src):  # pragma: no cover - compiled
    """Per right-hand side (C, B): inflow, outflow and absorbed power of one sweep from f, in float64.

    f in the block layout of ``_Operator``: node (x, y, z) at f[x, y // G, :, :, (y % G) * nz + z].
    Power is ``sum_i wq_i f_i`` (wq_i = 1 / |c_i| on the ``ordinates`` lattice, 1 on ``geist2008``:
    ``power_weights``). With ``use_src`` the inflow includes the beams' first-collision source
    s_i = cq[m, c, i, b] pw[x, y // G, c, ((y % G) nz + z) B + b] (``_Operator``).
    """
    nx, nb, nq, C, gnz, B = f.shape
    ny = rho.shape[1]
    nz = rho.shape[2]
    G = gnz // nz
    inflow = np.zeros((nx, C, B))
    outflow = np.zeros((nx, C, B))
    absorbed = np.zeros((nx, C, B))
    for x in prange(nx):
        for y in range(ny):
            yb = y // G
            for z in range(nz):
                zb = (y % G) * nz + z
                p = rho[x, y, z]
                pd = rhod[x, y, z]
                m = mat[x, y, z]
                boundary = x == 0 or y == 0 or z == 0 or x == nx - 1 or y == ny - 1 or z == nz - 1
                for c in range(C):
                    for b in range(B):
                        tot = 0.0
                        for j in range(nq):
                            pj = p if j < 2 * NAXIAL_PAIRS else pd
                            tot += pj * wq[j] * load(f[x, yb, j, c, zb, b])
                        absorbed[x, c, b] += sig_a[m, c] * tot  # moved into f_0 (geist2008 eq. 5), then removed
                        pnode = float(pw[x, yb, c, zb * B + b]) if use_src else 0.0
                        if use_src:
                            for i in range(nq):
                                inflow[x, c, b] += wq[i] * cq[m, c, i, b] * pnode
                        if not boundary:
                            continue
                        for i in range(nq):
                            if inflow_mask[x, y, z, i]:
                                inflow[x, c, b] += wq[i] * load(f[x, yb, i, c, zb, b])
                            tx = x + _CX[i]
                            ty = y + _CY[i]
                            tz = z + _CZ[i]
                            if 0 <= tx < nx and 0 <= ty < ny and 0 <= tz < nz:
                                continue
                            h = float(load(f[x, yb, i, c, zb, b]))
                            if p > 0:
                                s = 0.0
                                for j in range(nq):
                                    pj = p if j < 2 * NAXIAL_PAIRS else pd
                                    s += A[m, c, i, j] * pj * load(f[x, yb, j, c, zb, b])
                                h += s
                            if use_src:
                                h += cq[m, c, i, b] * pnode
                            outflow[x, c, b] += wq[i] * h
    return inflow.sum(axis=0), outflow.sum(axis=0), absorbed.sum(axis=0)


@njit(parallel=True, cache=True)
def _once_scattered(f, att_a, att_d, pw, cq, mat, ks, G):  # pragma: no cover - compiled
    """f[., q, ., ., k] for the beam right-hand sides ks: the first-collision source carried along each lattice line.

    The steady state of f_q(r) = f_q(r - c_q) att_q(r - c_q) + s_q(r - c_q) (0 in inflow slots), s_q =
    cq[m, c, q, k] pw[r, c, k], built in the order of the line (one pass per direction, exact for light
    scattered once); att_a / att_d: the per-step survival of axial / non-axial steps (nx, ny, nz, C).
    f in the block layout of ``_Operator`` and pw, the beams' power, in its run layout (nx, NB, C, G nz K):
    node (x, y, z) at [x, y // G, c, ((y % G) nz + z) K + k], so the right-hand sides are contiguous in both.
    Directions in parallel (each writes only its own slots).
    """
    nx, ny, nz, C = att_a.shape
    K = f.shape[5]
    for q in prange(NQ):
        cx, cy, cz = _CX[q], _CY[q], _CZ[q]
        att = att_a if q < 2 * NAXIAL_PAIRS else att_d
        for a in range(nx):
            x = a if cx >= 0 else nx - 1 - a
            for b in range(ny):
                y = b if cy >= 0 else ny - 1 - b
                for e in range(nz):
                    z = e if cz >= 0 else nz - 1 - e
                    ux, uy, uz = x - cx, y - cy, z - cz
                    zo = (y % G) * nz + z
                    if ux < 0 or ux >= nx or uy < 0 or uy >= ny or uz < 0 or uz >= nz:
                        for c in range(C):
                            for k in ks:
                                f[x, y // G, q, c, zo, k] = 0.0
                    else:
                        m = mat[ux, uy, uz]
                        zu = (uy % G) * nz + uz
                        for c in range(C):
                            out = f[x, y // G, q, c, zo]
                            up = f[ux, uy // G, q, c, zu]
                            src = pw[ux, uy // G, c, zu * K : zu * K + K]
                            t = att[ux, uy, uz, c]
                            for k in ks:
                                out[k] = convert(load(up[k]) * t + cq[m, c, q, k] * src[k], f)


@njit(parallel=True, cache=True)
def _put_transmitted(f, q, t, b, G):  # pragma: no cover - compiled
    """f[., q, ., ., k] = b[k] t as stored, for direction q of a field f in the block layout of ``_Operator``.

    t (nx, ny, nz, C): the never-scattered density arriving along q per unit inflow (``_transmit``); b (K,) the
    inflow of q per right-hand side, in t's dtype (the product is rounded once, as the float32 arithmetic of a
    sweep rounds it). The padding rows of the last block are left as they are (zero).
    """
    nx, ny, nz, C = t.shape
    K = b.size
    for x in prange(nx):
        for y in range(ny):
            off = (y % G) * nz
            for c in range(C):
                run = f[x, y // G, q, c]
                for z in range(nz):
                    v = t[x, y, z, c]
                    for k in range(K):
                        run[off + z, k] = convert(v * b[k], f)


@njit(parallel=True, cache=True)
def _field_energy(f, ny, out):  # pragma: no cover - compiled
    """out[x, y, z, k, c] = sum over the 18 directions of f (block layout, as stored), added in direction order."""
    nx, nb, nq, C, gnz, K = f.shape
    nz = out.shape[2]
    G = gnz // nz
    for x in prange(nx):
        for y in range(ny):
            off = (y % G) * nz
            blk = f[x, y // G]
            for z in range(nz):
                for k in range(K):
                    for c in range(C):
                        u = load(blk[0, c, off + z, k])
                        for q in range(1, nq):
                            u += load(blk[q, c, off + z, k])
                        out[x, y, z, k, c] = u


@njit(parallel=True, cache=True)
def _rounding_energy(f, rho, variance, rounded, norm):  # pragma: no cover - compiled
    """Per x-slab (nx, C, K), added to ``rounded``: the expected squared error of the rounding to binary16 (uint16
    ``f``, block layout) that the plain sweep which wrote f made, and to ``norm``: sum f^2.

    A sweep rounds the value it stores at node y in direction i when it collided there, i.e. when the node it
    came from, y - c_i, is occupied (rho > 0); a pass-through copy and an inflow slot are stored as they were.
    A rounded value's squared error is taken as ``variance[e]`` (``storage.HALF_ROUNDING_VARIANCE``) of its
    exponent field e.
    """
    nx, nb, nq, C, gnz, K = f.shape
    ny = rho.shape[1]
    nz = rho.shape[2]
    G = gnz // nz
    for x in prange(nx):
        for y in range(ny):
            blk = f[x, y // G]
            off = (y % G) * nz
            for z in range(nz):
                for i in range(nq):
                    ux = x - _CX[i]
                    uy = y - _CY[i]
                    uz = z - _CZ[i]
                    collided = 0 <= ux < nx and 0 <= uy < ny and 0 <= uz < nz and rho[ux, uy, uz] > 0
                    for c in range(C):
                        for k in range(K):
                            bits = blk[i, c, off + z, k]
                            v = load(bits)
                            norm[x, c, k] += v * v
                            if collided:
                                rounded[x, c, k] += variance[(bits >> 10) & 31]


@njit(parallel=True, cache=True)
def _copy_field(f):  # pragma: no cover - compiled
    """A copy of f (nx, ...), its x-slabs copied in parallel (numpy's one-thread copy of a fresh 3.5 GB field,
    page faults included, took 5.4 s at 128^3 fp16)."""
    out = np.empty_like(f)
    for x in prange(f.shape[0]):
        out[x] = f[x]
    return out


@njit(parallel=True, fastmath=True, cache=True)
def _dot(a, b, part):  # pragma: no cover - compiled
    """part[x, c, l] = sum over (y, i) of a*b; a, b : (nx, M, C, L)."""
    nx, M, C, L = a.shape
    for x in prange(nx):
        for c in range(C):
            p = part[x, c]
            for l in range(L):
                p[l] = 0.0
            for k in range(M):
                u = a[x, k, c]
                v = b[x, k, c]
                for l in range(L):
                    p[l] += u[l] * v[l]


@njit(parallel=True, fastmath=True, cache=True)
def _axpy_norm(y, alpha, x_, part):  # pragma: no cover - compiled
    """y <- y + alpha * x (alpha per (c, l)), with partial sums of y.y."""
    nx, M, C, L = y.shape
    for x in prange(nx):
        for c in range(C):
            q = part[x, c]
            al = alpha[c]
            for l in range(L):
                q[l] = 0.0
            for k in range(M):
                yy = y[x, k, c]
                xx = x_[x, k, c]
                for l in range(L):
                    w = yy[l] + al[l] * xx[l]
                    yy[l] = w
                    q[l] += w * w


@njit(parallel=True, fastmath=True, cache=True)
def _update_xr(xv, alpha, p, omega, r, t, rhat, part_xx, part_rr, part_hr):  # pragma: no cover - compiled
    """x <- x + alpha p + omega s and r <- s - omega t (r holds s), with partial sums of x.x, r.r, rhat.r."""
    nx, M, C, L = xv.shape
    for x in prange(nx):
        for c in range(C):
            q1 = part_xx[x, c]
            q2 = part_rr[x, c]
            q3 = part_hr[x, c]
            al = alpha[c]
            om = omega[c]
            for l in range(L):
                q1[l] = 0.0
                q2[l] = 0.0
                q3[l] = 0.0
            for k in range(M):
                xx = xv[x, k, c]
                pp = p[x, k, c]
                rr = r[x, k, c]
                tt = t[x, k, c]
                hh = rhat[x, k, c]
                for l in range(L):
                    sv = rr[l]
                    w = xx[l] + al[l] * pp[l] + om[l] * sv
                    xx[l] = w
                    q1[l] += w * w
                    u = sv - om[l] * tt[l]
                    rr[l] = u
                    q2[l] += u * u
                    q3[l] += hh[l] * u


@njit(parallel=True, fastmath=True, cache=True)
def _extrapolate(f, prev, factor):  # pragma: no cover - compiled
    """f <- f + factor (f - prev), factor per (c, l)."""
    nx, M, C, L = f.shape
    for x in prange(nx):
        for c in range(C):
            fa = factor[c]
            for k in range(M):
                ff = f[x, k, c]
                pp = prev[x, k, c]
                for l in range(L):
                    v = load(ff[l])
                    ff[l] = convert(v + fa[l] * (v - load(pp[l])), ff)


@njit(parallel=True, fastmath=True, cache=True)
def _p_update(p, r, v, beta, omega):  # pragma: no cover - compiled
    """p <- r + beta (p - omega v)."""
    nx, M, C, L = p.shape
    for x in prange(nx):
        for c in range(C):
            be = beta[c]
            om = omega[c]
            for k in range(M):
                pp = p[x, k, c]
                rr = r[x, k, c]
                vv = v[x, k, c]
                for l in range(L):
                    pp[l] = rr[l] + be[l] * (pp[l] - om[l] * vv[l])
