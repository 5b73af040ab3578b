"""Push-streaming pieces of the lattice-Boltzmann sweeps (numba): a run copied, collided or differenced into its target.

``_stream_piece`` writes one piece of a run in the sweep's mode; ``_stream_segment`` streams a source run into
a target block of ``_sweep_blocks``, keeping the inflow slots a z-shift wraps into; ``_copy`` and ``_fill`` are
the plain run copies of the in-place and ordered sweeps.
"""

from __future__ import annotations

from numba import njit

from foliage_tools.lighting.lb.storage import convert, load


@njit(fastmath=True, cache=True)
def _stream_piece(mode, acc, o, s, e, od, sg, fo, wo, q1, q2):  # pragma: no cover - compiled
    """o = v (modes 0, 1) or fo - v (mode 2) with v = s + e + sg * od (``e`` empty: v = s); with ``acc``
    also the mode's sums: q1 += (o - fo)^2 (mode 1), q1 += wo * o and q2 += o^2 (mode 2)."""
    n = o.size
    if e.size == 0:
        if mode == 0 or (mode == 1 and not acc):
            for l in range(n):
                o[l] = s[l]
        elif mode == 1:
            for l in range(n):
                v = s[l]
                dd = load(v) - load(fo[l])
                q1[l] += dd * dd
                o[l] = v
        elif not acc:
            for l in range(n):
                o[l] = convert(load(fo[l]) - load(s[l]), o)
        else:
            for l in range(n):
                w = load(fo[l]) - load(s[l])
                o[l] = convert(w, o)
                q1[l] += load(wo[l]) * w
                q2[l] += w * w
    else:
        # the residual sums (mode 1) take the value as stored: with fp16 storage the rounded one
        if mode == 0 or (mode == 1 and not acc):
            for l in range(n):
                o[l] = convert(load(s[l]) + e[l] + sg * od[l], o)
        elif mode == 1:
            for l in range(n):
                v = convert(load(s[l]) + e[l] + sg * od[l], o)
                dd = load(v) - load(fo[l])
                q1[l] += dd * dd
                o[l] = v
        elif not acc:
            for l in range(n):
                o[l] = convert(load(fo[l]) - (load(s[l]) + e[l] + sg * od[l]), o)
        else:
            for l in range(n):
                w = load(fo[l]) - (load(s[l]) + e[l] + sg * od[l])
                o[l] = convert(w, o)
                q1[l] += load(wo[l]) * w
                q2[l] += w * w


@njit(fastmath=True, cache=True)
def _stream_segment(mode, o, s, fo, wo, q1, q2, a, b, d, limit, wrap_z, B, Lr, e, od, sg, l0, l1, save, slots):  # pragma: no cover - compiled
    """Push-stream the source run [a, b) of one direction and channel into the target block ``o`` at offset d.

    ``o, fo, wo, q1, q2`` are the target block's runs in out, f, wt, part1, part2 (only [0, limit)
    holds real rows; a plain sweep passes ``s`` for fo and wo); ``s`` is the source block's run. On
    [l0, l1) the source collided: the target gets the post-collision ``s + e + sg * od`` there, ``s``
    elsewhere (mode 2: ``fo`` minus that). A z-shift moves a row's last (first) node into the next
    (previous) row's first (last) slot of the flat block: those targets are inflow slots on the z
    faces, so they are saved here and put back, and then the mode 1/2 sums are taken over the
    target run in a second pass while it is in cache (subtracting a wrong term again would leave
    float round-off in a residual that can be ~1e-14). Without such slots (z-shift 0, or one row
    per block) the sums are taken in the same pass. ``save`` and ``slots`` are scratch for the
    saved values (G B) and the wrapped slots' offsets (G).
    """
    a = max(a, -d)
    b = min(b, limit - d)
    if b <= a:
        return
    ns = 0  # wrapped slots: the target offsets of the source's z-face nodes in [a, b)
    if wrap_z >= 0:
        for g in range(a // Lr, (b + Lr - 1) // Lr):
            t = g * Lr + wrap_z * B + d
            if t - d >= a and t - d + B <= b and t >= 0 and t + B <= limit:
                slots[ns] = t
                for k in range(B):
                    save[ns * B + k] = o[t + k]
                ns += 1
    acc = ns == 0
    none = e[:0]
    c1 = min(b, l0)
    if c1 > a:
        x0 = a + d
        x1 = c1 + d
        _stream_piece(mode, acc, o[x0:x1], s[a:c1], none, none, sg, fo[x0:x1], wo[x0:x1], q1[x0:x1], q2[x0:x1])
    c0 = max(a, l0)
    c1 = min(b, l1)
    if c1 > c0:
        x0 = c0 + d
        x1 = c1 + d
        _stream_piece(mode, acc, o[x0:x1], s[c0:c1], e[c0 - l0 : c1 - l0], od[c0 - l0 : c1 - l0], sg, fo[x0:x1],
                      wo[x0:x1], q1[x0:x1], q2[x0:x1])
    c0 = max(a, l1)
    if b > c0:
        x0 = c0 + d
        x1 = b + d
        _stream_piece(mode, acc, o[x0:x1], s[c0:b], none, none, sg, fo[x0:x1], wo[x0:x1], q1[x0:x1], q2[x0:x1])
    if ns == 0:
        return
    for w in range(ns):
        t = slots[w]
        for k in range(B):
            o[t + k] = save[w * B + k]
    if mode == 1:
        oo = o[a + d : b + d]
        ff = fo[a + d : b + d]
        r1 = q1[a + d : b + d]
        for l in range(b - a):
            dd = load(oo[l]) - load(ff[l])
            r1[l] += dd * dd
    elif mode == 2:
        oo = o[a + d : b + d]
        ww = wo[a + d : b + d]
        r1 = q1[a + d : b + d]
        r2 = q2[a + d : b + d]
        for l in range(b - a):
            w = load(oo[l])
            r1[l] += load(ww[l]) * w
            r2[l] += w * w


@njit(fastmath=True, cache=True)
def _fill(run, values, B):  # pragma: no cover - compiled
    """run[j B + k] = values[k] for every node j of the run."""
    for j in range(run.size // B):
        for k in range(B):
            run[j * B + k] = values[k]


@njit(fastmath=True, cache=True)
def _copy(dst, src):  # pragma: no cover - compiled
    """dst[:] = src for equal-length runs of distinct arrays (a loop: numba's slice assignment checks for overlap)."""
    for l in range(dst.size):
        dst[l] = src[l]
