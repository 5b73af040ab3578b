"""The fast path's far field: the linearised sums of eq. (1) (``reference.py``) by FFT on a grid.

The leaves' masses (the projection fit of ``projection.py``) are deposited
on the grid's nodes (cloud-in-cell), correlated with the band-limited
kernels of the 8 octants by FFTs that skip the zero padding, and read back
at the leaves; the split is described in ``fast.py``.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import scipy.fft
from numba import njit, prange

from foliage_tools.lighting.envelope.directions import BIN_SOLID_ANGLE, N_DIRECTIONS
from foliage_tools.lighting.envelope.grid import _cell


@njit(cache=True)
def _deposit(x, mass, lo, h, shape, grid):
    """Cloud-in-cell deposit of per-leaf masses (L, G) onto the node grid (nx, ny, nz, G).

    Channels last: a node's G channels share cache lines (faster than G
    separate grids; measured: ``docs/envelope_notes.md``).
    """
    for i in range(x.shape[0]):
        i0, j0, k0, fu, fv, fw = _cell(x, i, lo, h, shape)
        for di in range(2):
            wu = fu if di else 1.0 - fu
            for dj in range(2):
                wv = fv if dj else 1.0 - fv
                for dk in range(2):
                    wk = fw if dk else 1.0 - fw
                    wt = wu * wv * wk
                    for g in range(mass.shape[1]):
                        grid[i0 + di, j0 + dj, k0 + dk, g] += wt * mass[i, g]


@njit(parallel=True, cache=True)
def _interpolate(x, lo, h, shape, field, own_mass, kdiag, floor, out):
    """Far-field sums at the leaves, added to ``out`` (L, 8), from node fields (8, nx, ny, nz).

    Trilinear (cloud-in-cell) interpolation of octant j's field; a value below
    ``floor`` is float32 FFT round-off in an empty bin and counts as 0. Then
    the leaf's own mass is removed: it was deposited on the 8 nodes of its
    cell and is read back through the same nodes, and with r_1 >= √2 h the
    kernel vanishes on all offsets within a cell except the 8 cell diagonals,
    one per octant, each with weight Π f(1 - f): ``kdiag`` (the kernels'
    scale h^-power) × that × ``own_mass`` (L, 4), the leaf's masses times the
    kernels on the diagonal (h = 1, ``_far_kernel_spectra``), for octant pair
    min(j, 7 - j).
    """
    for i in prange(x.shape[0]):
        i0, j0, k0, fu, fv, fw = _cell(x, i, lo, h, shape)
        fu = min(max(fu, 0.0), 1.0)
        fv = min(max(fv, 0.0), 1.0)
        fw = min(max(fw, 0.0), 1.0)
        own = kdiag * fu * (1.0 - fu) * fv * (1.0 - fv) * fw * (1.0 - fw)
        for b in range(field.shape[0]):
            val = 0.0
            for di in range(2):
                wu = fu if di else 1.0 - fu
                for dj in range(2):
                    wv = fv if dj else 1.0 - fv
                    for dk in range(2):
                        wk = fw if dk else 1.0 - fw
                        val += wu * wv * wk * field[b, i0 + di, j0 + dj, k0 + dk]
            if val < floor:
                val = 0.0
            out[i, b] += val - own * own_mass[i, min(b, 7 - b)]


def _smoothstep_down(r, r_a: float, r_b: float):
    """1 for r <= r_a, 0 for r >= r_b, the C¹ smoothstep between (the near/far blend w)."""
    t = np.clip((r_b - r) / (r_b - r_a), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _band_weight(r, band):
    """Radial weight of a far-field band (r_a, r_b, r_c, r_d) in cells: (1 - w(r_a, r_b)) w(r_c, r_d).

    0 up to r_a, rising to 1 at r_b (the hand-over from the near field or a
    finer grid), falling from 1 at r_c to 0 at r_d (the hand-over to a coarser
    grid; r_c = inf: none).
    """
    r_a, r_b, r_c, r_d = band
    w = np.where(r > r_a, 1.0 - _smoothstep_down(r, r_a, r_b), 0.0)
    if math.isfinite(r_c):
        w = w * _smoothstep_down(r, r_c, r_d)
    return w


@lru_cache(maxsize=8)
def _far_kernel_spectra(shape, pad, band, power: int, fit: bool) -> tuple[np.ndarray, np.ndarray]:
    """rFFTs complex64 of the far-field kernels of octant 0 (x, y, z < 0), for correlation, with h = 1.

    K_0(v) = ``_band_weight``(|v|) / (Ω |v|^power) times the octant membership
    (1/2 per zero component: the node sits on a bin plane). ``fit``: 4
    kernels, K_0 and K_0 |v_k| / |v| for k = x, y, z (the linear terms of the
    projection fit, see ``_octant_projection``); else K_0 alone. power 2
    gives the linearised optical depth of eq. (1) (``reference.py``), power 1 gives S1 = Σ o r.
    For a cell size h the kernels scale by h^-power. Correlation D(x) = Σ_v
    K(v) m(x + v) is a convolution with K(-v), whose support -v >= 0 fills
    the corner [0, extent) of the wrap-around array (extent: the band's outer
    radius, or the grid). Also returns the kernels' values on the cell
    diagonal (1, 1, 1) (see ``_interpolate``). Cached (read-only): the same
    grid shape gives the same spectra.
    """
    extent = [s if not math.isfinite(band[3]) else min(s, math.ceil(band[3]) + 1) for s in shape]
    ii, jj, kk = np.meshgrid(*[np.arange(s, dtype=np.float64) for s in extent], indexing="ij", sparse=True)
    frac = np.where(ii == 0, 0.5, 1.0) * np.where(jj == 0, 0.5, 1.0) * np.where(kk == 0, 0.5, 1.0)
    r = np.sqrt(ii * ii + jj * jj + kk * kk)
    rr = np.maximum(r, 1.0)  # the weight is 0 below r_a >= √2
    k0 = frac * _band_weight(r, band) / (BIN_SOLID_ANGLE * rr**power)
    comps = (ii, jj, kk) if fit else ()
    kern = np.empty((1 + len(comps),) + tuple(extent), dtype=np.float32)
    kern[0] = k0
    for c, comp in enumerate(comps):
        kern[c + 1] = k0 * comp / rr
    spec = _rfftn_padded(kern, pad)
    spec.setflags(write=False)
    diag = math.sqrt(3.0)
    kd = float(_band_weight(np.array(diag), band)) / (BIN_SOLID_ANGLE * diag**power)
    kdiag = np.array([kd] + [kd / diag] * len(comps))
    kdiag.setflags(write=False)
    return spec, kdiag


def _rfftn_padded(grid: np.ndarray, pad, out: np.ndarray | None = None) -> np.ndarray:
    """``scipy.fft.rfftn(grid, s=pad, axes=(1, 2, 3))`` without transforming the zero padding.

    The input fills only the corner [0, s) of the padded box, so each 1-D pass
    runs over the rows that are not all zero: the last axis on s0 s1 rows, the
    first one on s1 (p2/2+1) rows, the middle one on p0 (p2/2+1) rows (the
    strided first axis before the middle one is the faster order: ``docs/envelope_notes.md``).
    The passes run in place in ``out`` (complex64, (G, p0, p1, p2/2+1)) if
    given: reusing one buffer avoids touching fresh memory for every call.
    """
    g, s0, s1, _ = grid.shape
    if out is None:
        out = np.empty((g, pad[0], pad[1], pad[2] // 2 + 1), dtype=np.complex64)
    out[:, :s0, :s1] = scipy.fft.rfft(grid, n=pad[2], axis=3, workers=-1)
    out[:, s0:, :s1] = 0.0
    scipy.fft.fft(out[:, :, :s1], axis=1, workers=-1, overwrite_x=True)
    out[:, :, s1:] = 0.0
    scipy.fft.fft(out, axis=2, workers=-1, overwrite_x=True)
    return out


def _irfftn_cropped(spec: np.ndarray, pad, shape) -> np.ndarray:
    """``scipy.fft.irfftn(spec, s=pad, axes=(1, 2, 3))[:, :s0, :s1, :s2]`` computing only the kept corner.

    The inverse passes are separable, so cropping each axis right after its
    pass gives the same values while the later passes run on fewer rows. The
    first two passes run in place: ``spec`` is overwritten.
    """
    scipy.fft.ifft(spec, axis=1, workers=-1, overwrite_x=True)
    out = spec[:, : shape[0]]
    scipy.fft.ifft(out, axis=2, workers=-1, overwrite_x=True)
    return scipy.fft.irfft(out[:, :, : shape[1]], n=pad[2], axis=3, workers=-1)[..., : shape[2]]


def _grid_pad(shape, band) -> tuple[int, int, int]:
    """FFT sizes for a linear (not wrap-around) correlation of the grid with a band's kernel.

    A kernel reaching S cells needs s + S (zero padding catches what wraps
    around); the whole grid, 2 s - 1.
    """
    reach = math.ceil(band[3]) if math.isfinite(band[3]) else None
    return tuple(
        scipy.fft.next_fast_len(2 * s - 1 if reach is None else min(s + reach, 2 * s - 1), real=True) for s in shape
    )


def _touched_zeros(shape, dtype) -> np.ndarray:
    """``np.zeros`` with its pages touched now, in order, by one thread.

    np.zeros of a large array maps fresh pages that are zeroed on first touch;
    touched in random order (a deposit) or by parallel threads (a prange
    kernel) such page faults are costly (measured: ``docs/envelope_notes.md``).
    """
    out = np.empty(shape, dtype=dtype)
    out.fill(0)
    return out


def _far_field(x, mass, lo, h, shape, kernels) -> list[np.ndarray]:
    """Far-field sums Σ_{q != P} band(r) 1_{octant j} m_q(v^) / (Ω r^power) at the leaves, grid of step h.

    ``mass`` (L, 4, C): per leaf and octant pair, C = 4: the projection fit
    (a, β_x, β_y, β_z) of ``_octant_projection``, m_q(v^) = a + β·|v^|; C =
    1: a mass without direction. ``kernels``: (band in cells, power) pairs,
    see ``_band_weight``; all bands must share the FFT sizes, i.e. the outer
    radius of the first. One (L, 8) array per kernel. The masses are deposited
    once; each octant pair's C channels are transformed once and multiplied
    into the spectra of its two octants (one pair at a time keeps the
    transform's buffers at a quarter of the size).
    """
    shape = tuple(int(s) for s in shape)
    shape_arr = np.array(shape, dtype=np.int64)
    n_leaves, _, nc = mass.shape
    grid = _touched_zeros(shape + (4 * nc,), np.float32)
    _deposit(x, np.ascontiguousarray(mass.reshape(n_leaves, 4 * nc)), lo, h, shape_arr, grid)
    pad = _grid_pad(shape, kernels[0][0])
    kspecs = [_far_kernel_spectra(shape, pad, tuple(round(b, 12) for b in band), int(power), nc == 4) for band, power in kernels]
    specs = [np.empty((N_DIRECTIONS,) + kspecs[0][0].shape[1:], dtype=np.complex64) for _ in kernels]
    mspec = np.empty((nc,) + specs[0].shape[1:], dtype=np.complex64)
    for pair in range(4):
        _rfftn_padded(np.ascontiguousarray(np.moveaxis(grid[..., nc * pair : nc * (pair + 1)], 3, 0)), pad, mspec)
        for (_, power), (kspec, _), spec in zip(kernels, kspecs, specs):
            _octant_spectra(mspec, kspec, np.float32(h ** (-power)), pair, spec)
    del grid, mspec
    results = []
    for (_, power), (_, kdiag), spec in zip(kernels, kspecs, specs):
        fields = _irfftn_cropped(spec, pad, shape)  # a cropped view: read in place
        # the leaf's own mass read back through the cell diagonals (see _interpolate)
        own_mass = np.ascontiguousarray(mass @ kdiag)
        # float32 FFT round-off (~1e-7 of the largest value) would leave empty bins
        # slightly non-zero: what is below 1e-6 of the largest counts as 0
        floor = 1e-6 * max(float(fields.max(initial=0.0)), -float(fields.min(initial=0.0)))
        out = _touched_zeros((n_leaves, N_DIRECTIONS), np.float64)
        _interpolate(x, lo, h, shape_arr, fields, own_mass, h ** (-power), floor, out)
        results.append(out)
    return results


@njit(parallel=True, cache=True)
def _octant_spectra(mspec, kspec, scale, j, out):
    """out[j], out[7 - j] = scale × Σ_c mspec[c] × spectrum of kernel c of that octant (j < 4).

    ``mspec`` holds the C channels of octant pair j, ``kspec`` octant 0's C
    kernels. Octant j's kernels are octant 0's reflected along the axes where
    j is positive (x if j&1, z if j&2; y is negative for j < 4): k_j(u) =
    k_0(S u) (the |v_k| factors are unchanged by reflections), whose
    spectrum is F[k_0](S ξ). The last axis of an rFFT holds only ξ3 >= 0, so
    a flip of it uses F(ξ1, ξ2, -ξ3) = conj F(-ξ1, -ξ2, ξ3), true for any
    real kernel. Octant 7 - j is octant j reflected along all three axes, so
    its spectrum is the conjugate of octant j's: both come from the same four
    real products per channel.
    """
    nc, p0, p1, n2 = kspec.shape
    conj = (j & 2) != 0
    neg0 = (j & 1) != 0
    if conj:
        neg0 = not neg0
    sgn = np.float32(-1.0) if conj else np.float32(1.0)
    for i0 in prange(p0):
        a0 = np.int64(i0)  # prange's index may be unsigned: keep the reflected index an integer
        k0 = (p0 - a0) % p0 if neg0 else a0
        # float32 sums over the channels of Re m Re k, Im m Im k, Re m Im k, Im m Re k, one row at a time
        rr = np.empty(n2, dtype=np.float32)
        ii = np.empty(n2, dtype=np.float32)
        ri = np.empty(n2, dtype=np.float32)
        ir = np.empty(n2, dtype=np.float32)
        for i1 in range(p1):
            k1 = (p1 - i1) % p1 if conj else i1
            rr[:] = 0.0
            ii[:] = 0.0
            ri[:] = 0.0
            ir[:] = 0.0
            for c in range(nc):
                for i2 in range(n2):
                    kv = kspec[c, k0, k1, i2]
                    mv = mspec[c, i0, i1, i2]
                    kr = kv.real
                    ki = sgn * kv.imag
                    rr[i2] += mv.real * kr
                    ii[i2] += mv.imag * ki
                    ri[i2] += mv.real * ki
                    ir[i2] += mv.imag * kr
            for i2 in range(n2):
                out[j, i0, i1, i2] = complex(scale * (rr[i2] - ii[i2]), scale * (ri[i2] + ir[i2]))
                out[7 - j, i0, i1, i2] = complex(scale * (rr[i2] + ii[i2]), scale * (ir[i2] - ri[i2]))
