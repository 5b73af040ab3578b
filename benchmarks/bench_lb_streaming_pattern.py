"""Issue 21: how fast the LB sweep's memory pattern can go, push streaming against in-place (AA-pattern) streaming.

Usage::

    python benchmarks/bench_lb_streaming_pattern.py

The 3-rhs sweep kernel (``lighting.lb.kernels_sweep``) pushes each node's 18 post-collision runs into a second
field at shifted offsets: every value is read once and written once to another array, and each written cache line
is first read for ownership (216 bytes moved per node x rhs update where the roofline model counts 152). An
in-place scheme (the AA pattern: a step writes each value back where it was read, the odd steps along the lattice
links) moves each value once each way with no read-for-ownership and holds one field instead of two.

This times the two patterns alone, no collision, on 18 runs of 4096 float32 per block (the kernel's run length,
``layout._BLOCK_VALUES``) over ~300 MB, against the numba STREAM triad of the same run:

* push: run q of block b (of b + 1 for odd q) copied, scaled, into run q of ``out`` shifted by d_q values;
* in place, unshifted: run pairs (2p, 2p + 1) of a block swapped and scaled in place (the AA even step);
* in place, shifted: the same with one run of the pair shifted by d_p (the odd step's moves along a link).

The last row is the product's own sweep (``_Operator.sweep``) on an empty 128^3 grid with 3 rhs: its push
streaming alone, the part of the 3-rhs sweep the pattern would change. Best of 7 after a warm-up; GB/s count 8 bytes per value (read + write), so the push pattern's read-for-ownership
is in its time but not in its bytes. Nothing here is a test, and these are patterns, not the kernel: the scale by
0.999 stands in for work per value.
"""

from __future__ import annotations

import os
import time

import numpy as np
from numba import njit, prange

L = 4096  # values per run (layout._BLOCK_VALUES)
NB = 1024  # blocks: 1024 x 18 x 4096 float32 = 302 MB per field


@njit(parallel=True, fastmath=True, cache=True)
def _push(f, out):  # pragma: no cover - compiled
    nb = f.shape[0]
    for bi in prange(nb):
        b = np.int64(bi)
        for q in range(18):
            d = (q % 7) * 3 - 9
            bb = b + 1 if (q % 2 == 1 and b + 1 < nb) else b
            src = f[bb, q]
            dst = out[b, q]
            for l in range(max(0, -d), min(L, L - d)):
                dst[l + d] = src[l] * np.float32(0.999)


@njit(parallel=True, fastmath=True, cache=True)
def _in_place(f, shifted):  # pragma: no cover - compiled
    for bi in prange(f.shape[0]):
        b = np.int64(bi)
        for p in range(9):
            d = (p % 7) * 3 - 9 if shifted else 0
            a = f[b, 2 * p]
            c = f[b, 2 * p + 1]
            for l in range(max(0, -d), min(L, L - d)):
                t = a[l + d]
                a[l + d] = c[l] * np.float32(0.999)
                c[l] = t * np.float32(0.999)


@njit(parallel=True, cache=True)
def _triad(a, b, c, s):  # pragma: no cover - compiled
    for i in prange(a.size):
        a[i] = b[i] + s * c[i]


def _best(fn, *args, repeats=7):
    fn(*args)
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn(*args)
        times.append(time.perf_counter() - t)
    return min(times)


def main() -> None:
    rng = np.random.default_rng(0)
    print(f"bench_lb_streaming_pattern: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}")
    a, b, c = (rng.random(2**26, dtype=np.float32) for _ in range(3))
    t = _best(_triad, a, b, c, np.float32(0.5))
    print(f"   numba STREAM triad             {12 * a.size / t / 1e9:6.1f} GB/s (12 B/element)")
    del a, b, c
    f = rng.random((NB, 18, L), dtype=np.float32)
    out = np.zeros_like(f)
    rows = (("push (read f, write out)", _push, (f, out)), ("in place, unshifted (AA even)", _in_place, (f, False)),
            ("in place, shifted (AA odd)", _in_place, (f, True)))
    base = None
    for name, fn, args in rows:
        t = _best(fn, *args)
        base = base or t
        print(f"   {name:30s} {t * 1e3:6.1f} ms  {8 * f.size / t / 1e9:6.1f} GB/s (8 B/value)  {base / t:4.2f}x push")
    del f, out
    # the product's own sweep with nothing to collide (rho = 0: pure push streaming), 3 rhs (sun, RGB), 128^3
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from foliage_tools.lighting.lb.collision import leaf_medium
    from foliage_tools.lighting.lb import LBProblem, _Operator, sun_boundary

    n = 128
    op = _Operator(LBProblem(np.zeros((n, n, n)), leaf_medium(), (sun_boundary((0.3, 0.2, 0.9)),)), "float32")
    g = op.initial()
    h = g.copy()
    t = _best(lambda: op.sweep(g, h, residual=False))
    values = n**3 * 18 * op.C * op.K
    print(f"   {'the sweep kernel, rho = 0':30s} {t * 1e3:6.1f} ms  {8 * values / t / 1e9:6.1f} GB/s (8 B/value), "
          f"{n}^3 x 3 rhs (push streaming as the product does it)")


if __name__ == "__main__":
    main()
