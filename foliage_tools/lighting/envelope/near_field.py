"""The fast path's near field: the exact terms of eq. (1) (``reference.py``) for pairs within r_2, by cell lists.

Each term is weighted by the smoothstep w(r) that hands over to the far
field (``far_field.py``) between r_1 and r_2; the split is described in
``fast.py``.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba import njit, prange

from foliage_tools.lighting.envelope.directions import BIN_SOLID_ANGLE, N_DIRECTIONS, _octant
from foliage_tools.lighting.envelope.grid import _axis_max, _cell_index


@njit(cache=True, inline="always")
def _neg_log1m(o: float) -> float:
    """-ln(1 - o) for 0 <= o < 1; a Taylor series below 0.05 (error < o⁷/7 < 1.2e-10) saves log1p."""
    if o < 0.05:
        return o * (1.0 + o * (0.5 + o * (1.0 / 3.0 + o * (0.25 + o * (0.2 + o / 6.0)))))
    return -math.log1p(-o)


@njit(cache=True, inline="always")
def _axis_gap(p: float, lo: float, hi: float) -> float:
    if p < lo:
        return lo - p
    if p > hi:
        return p - hi
    return 0.0


_NEAR_BLOCK = 128


@njit(parallel=True, cache=True, error_model="numpy", fastmath=True)
def _near_kernel(x, an, cell, start, order, lo, h, shape, r1, r2, inv_omega, max_occ, depth, s1, lanes):
    """Exact near-field sums: w(r) -ln(1 - o) into ``depth`` and w(r) o r into ``s1``.

    Leaves are sorted by cell (``start``: CSR offsets of cells of size
    ``h`` >= r_2/2, so neighbours lie at most 2 cells away; ``order``: the
    caller's index of each sorted leaf, under which the sums are written);
    ``an`` is area × unit normal. fastmath: the sums may be reassociated
    (changes ~1e-15 relative; all inputs are finite). Every unordered pair is
    visited once, from its lower sorted index p, and adds to both leaves:
    o(p, q) = A_q |N_q·d^|/(Ω r²) to p's bin b of d = q - p, o(q, p) =
    A_p |N_p·d^|/(Ω r²) to q's bin of -d (the opposite octant 7 - b, except
    where a component of d is exactly 0, as for coplanar or mirrored leaves:
    the reference path counts it as not positive from both ends); a leaf p in
    the slab of cells i along the first axis has its partners q > p in slabs
    i..i+2. The leaves are dealt in chunks of 256, round robin, to ``lanes``
    parallel lanes, each adding into its own (L, 16) sums (8 bins of D, then
    8 of S1), which are added up at the end: faster than three lock-free
    passes over slabs taken 3 apart (few slabs of uneven weight per pass;
    measured: ``docs/envelope_notes.md``), for lanes x L x 128 bytes (26 MB
    at 100k leaves and 2 lanes). Each term is w -ln(1 - o), the log of the
    reference path's visibility factor (eq. (1) in ``reference.py``: a sum of logs
    instead of the log of a product, so nothing to renormalise), with the
    smoothstep w = 1 within r_1 (clamped, no branch). The candidates of a row
    of cells are first compacted (branch-free) to those within r_2.
    """
    n_leaves = x.shape[0]
    accs = np.zeros((lanes, n_leaves, 16))  # per lane: D in bins 0-7, S1 in 8-15
    r2sq = r2 * r2
    inv_span = 1.0 / (r2 - r1)
    nchunk = (n_leaves + 255) // 256
    pairs = np.zeros(lanes, dtype=np.int64)
    for lane in prange(lanes):
        acc = accs[lane]
        buf = np.empty(_NEAR_BLOCK, dtype=np.int64)
        npairs = 0
        for s in range(lane, nchunk, lanes):
            for p in range(s * 256, min(n_leaves, (s + 1) * 256)):
                i_home = cell[p, 0]
                px = x[p, 0]
                py = x[p, 1]
                pz = x[p, 2]
                k_lo = max(cell[p, 2] - 2, 0)
                k_hi = min(cell[p, 2] + 2, shape[2] - 2)
                for i in range(i_home, min(i_home + 2, shape[0] - 2) + 1):
                    gx = _axis_gap(px, lo[0] + i * h, lo[0] + (i + 1) * h)
                    gx *= gx
                    if gx >= r2sq:
                        continue
                    for j in range(max(cell[p, 1] - 2, 0), min(cell[p, 1] + 2, shape[1] - 2) + 1):
                        gy = _axis_gap(py, lo[1] + j * h, lo[1] + (j + 1) * h)
                        if gx + gy * gy >= r2sq:
                            continue
                        row = (i * shape[1] + j) * shape[2]
                        q_end = start[row + k_hi + 1]
                        for q_start in range(max(start[row + k_lo], p + 1), q_end, _NEAR_BLOCK):
                            cnt = 0
                            for q in range(q_start, min(q_start + _NEAR_BLOCK, q_end)):
                                dx = x[q, 0] - px
                                dy = x[q, 1] - py
                                dz = x[q, 2] - pz
                                rsq = dx * dx + dy * dy + dz * dz
                                buf[cnt] = q
                                cnt += (rsq < r2sq) & (rsq > 0.0)  # duplicates of P excluded
                            npairs += cnt
                            for c in range(cnt):
                                q = buf[c]
                                dx = x[q, 0] - px
                                dy = x[q, 1] - py
                                dz = x[q, 2] - pz
                                rsq = dx * dx + dy * dy + dz * dz
                                r = math.sqrt(rsq)
                                # boulanger2008 sec. 5.6: subtended solid angle A'|N'.d^|/r² over Ω_j
                                scale = inv_omega / (rsq * r)
                                o_pq = min(abs(an[q, 0] * dx + an[q, 1] * dy + an[q, 2] * dz) * scale, max_occ)
                                o_qp = min(abs(an[p, 0] * dx + an[p, 1] * dy + an[p, 2] * dz) * scale, max_occ)
                                b = _octant(dx, dy, dz)
                                # P's octant seen from q: 7 - b unless a component is exactly 0, which
                                # counts as not positive from both ends (the reference path's rule)
                                bq = _octant(-dx, -dy, -dz)
                                t = min(max((r2 - r) * inv_span, 0.0), 1.0)
                                w = t * t * (3.0 - 2.0 * t)
                                acc[p, b] += w * _neg_log1m(o_pq)
                                acc[p, 8 + b] += w * o_pq * r
                                acc[q, bq] += w * _neg_log1m(o_qp)
                                acc[q, 8 + bq] += w * o_qp * r
        pairs[lane] = npairs
    for p in prange(n_leaves):  # back to the caller's leaf order
        for b in range(8):
            dsum = 0.0
            ssum = 0.0
            for t in range(lanes):
                dsum += accs[t, p, b]
                ssum += accs[t, p, 8 + b]
            depth[order[p], b] = dsum
            s1[order[p], b] = ssum
    return 2 * pairs.sum()


def _near_sums(x, nl, area, lo, r1, r2, max_occlusion) -> tuple[np.ndarray, np.ndarray, int]:
    """Near-field D and S1 (L, 8) of every leaf, and the number of (ordered) pairs within r_2.

    Σ over the other leaves q within r_2 of w(r) -ln(1 - o) and w(r) o r, w
    the smoothstep from 1 at r_1 to 0 at r_2; a cell list with cells of r_2/2
    (neighbours at most 2 cells away), leaves sorted by cell.
    """
    hn = 0.5 * r2
    nshape = np.array([math.floor(e / hn) + 2 for e in (_axis_max(x) - lo)], dtype=np.int64)
    order, start, xs, ans, cs = _cell_sort(x, nl * area[:, None], lo, hn, nshape)
    depth = np.empty((x.shape[0], N_DIRECTIONS))
    s1 = np.empty_like(depth)
    pairs = _near_kernel(xs, ans, cs, start, order, lo, hn, nshape, r1, r2, 1.0 / BIN_SOLID_ANGLE,
                         float(max_occlusion), depth, s1, numba.get_num_threads())
    return depth, s1, int(pairs)


@njit(cache=True)
def _cell_sort(x, an, lo, h, shape):
    """Counting sort of the leaves by cell: (order, CSR offsets ``start``, x, an, cell in that order)."""
    n = x.shape[0]
    cell, lin = _cell_index(x, lo, h, shape)
    n_cells = shape[0] * shape[1] * shape[2]
    start = np.zeros(n_cells + 1, dtype=np.int64)
    for i in range(n):
        start[lin[i] + 1] += 1
    for c in range(n_cells):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    order = np.empty(n, dtype=np.int64)
    for i in range(n):
        order[fill[lin[i]]] = i
        fill[lin[i]] += 1
    xs = np.empty_like(x)
    ans = np.empty_like(an)
    cs = np.empty_like(cell)
    for k in range(n):
        i = order[k]
        for a in range(3):
            xs[k, a] = x[i, a]
            ans[k, a] = an[i, a]
            cs[k, a] = cell[i, a]
    return order, start, xs, ans, cs
