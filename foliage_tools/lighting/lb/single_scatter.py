"""Exact once-scattered light of a beam in a voxel medium: the single-scattering correction of ``lb``.

Why
---
The lattice's 18 ordinates integrate the once-scattered radiance badly where
it is sharply peaked in angle. Near the top and bottom of a leaf layer the
radiance arriving from near-horizontal directions is the local source over
its own extinction, while a few degrees off the horizontal it comes from a
short path through the thin top (or bottom) of the layer: a narrow peak
around mu = 0, which the lattice weights with its 8 horizontal ordinates, 40 %
of its quadrature weight. That is why LB's E_scattered stays +16 … +27 % high
in the top and bottom depth bins of a uniform layer at r = t = 0.1, where the
light is mostly once scattered, at every resolution (issue #15;
``benchmarks/bench_lb_layer.py``). The cure is the one of Nakajima & Tanaka
(1988, JQSRT 40, 51, "TMS" correction, eq. 14-15): compute the once-scattered
light exactly and keep only the higher orders from the discrete ordinates,

    u = u_lattice - u_lattice,1 + u_1                                   (1)

where u_lattice,1 is the lattice's own first-order field (its first-collision
source carried along the lattice lines with attenuation only,
``lb.LBResult.once_scattered``) and u_1 the exact one computed here. The
higher orders are smoother in angle, so the lattice's quadrature errs less
on them; they still start from the lattice's first order.

What is computed
----------------
For a unit beam travelling along d (``lb.beam_fields``: ``power(r)``, the
power a cell takes out of the beam per unit volume, lattice spacing 1), the
once-scattered emission per unit volume and solid angle toward Omega is

    J(r, Omega) = (sigma_s / sigma_t)(r) power(r) p_r(d . Omega) / (4 pi)   (2)

(p normalised to (1/4pi) int p dOmega = 1; the node's material's phase: the
bi-Lambertian canopy phase of ``collision`` or HG), and the once-scattered
scalar irradiance at a node centre x

    u_1(x) = int_4pi dOmega int_0^inf ds J(x - s Omega, Omega) exp(-tau(x, x - s Omega)).   (3)

The medium is piecewise constant per cell (extinction ``ext`` per lattice
spacing, as ``lb.beam_fields``), so the s-integral is exact per cell segment of
length l: J (1 - exp(-ext l)) / ext times the transmittance to the segment,
marched cell by cell (Amanatides & Woo 1987) from x until it leaves the grid
or the transmittance falls below ``T_MIN``. Omega runs over a spherical
Fibonacci set of M directions with weights 4 pi / M (its cosines to the z axis
are the midpoints of M/4 equal intervals of [-1, 1], so a layer's mu-dependence is
integrated by the midpoint rule; four azimuths a quarter turn apart per cosine); p is normalised on that set so the
scattered power is conserved exactly.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from foliage_tools.lighting.lb.collision import _bilambertian, _check_phase, _hg_relative
from foliage_tools.lighting.depth import _next_boundary

__all__ = ["DEFAULT_DIRECTIONS", "T_MIN", "fibonacci_directions", "once_scattered_energy"]

#: Directions over the sphere. The uniform layer's depth bins against the exact slab and the per-leaf error on
#: three trees against the Monte Carlo reference changed by < 0.2 % and < 0.003 from 32 to 64 and 128 (issue #15).
DEFAULT_DIRECTIONS = 64
#: A march stops once the transmittance back to the node is below this (the rest adds < T_MIN of the source).
T_MIN = 1e-3


def fibonacci_directions(m: int) -> np.ndarray:
    """(m, 3) unit vectors, m a multiple of 4: a spherical Fibonacci set of m / 4 points, each with its
    copies turned by 90, 180 and 270 degrees about z.

    The base points have z_i = 1 - (2i + 1)/(m/4) and golden-angle azimuths; the turned copies make the set
    invariant under the lattice's quarter turns about z, so a prototype turned by 90 degrees under a sun
    turned with it bakes the same values (tests/integration/test_lb_instances.py).
    """
    if m < 4 or m % 4:
        raise ValueError(f"the number of directions must be a positive multiple of 4, got {m}")
    q = m // 4
    i = np.arange(q)
    z = 1.0 - (2.0 * i + 1.0) / q
    phi = math.pi * (3.0 - math.sqrt(5.0)) * i
    s = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    out = [np.stack([s * np.cos(phi + k * math.pi / 2), s * np.sin(phi + k * math.pi / 2), z], axis=1) for k in range(4)]
    return np.concatenate(out)


def _phase_on(dirs: np.ndarray, d: np.ndarray, g: float, phase: str) -> np.ndarray:
    """p(d . Omega_m) on the direction set, normalised so its mean over the set is 1 (eq. 2)."""
    g = _check_phase(phase, g)
    mu = np.clip(dirs @ d, -1.0, 1.0)
    if phase == "bilambertian":
        p = np.maximum(_bilambertian(mu, g), 0.0)
    elif abs(g) < 1.0:
        p = _hg_relative((1.0 - mu)[:, None], (1.0 + mu)[:, None], g)[:, 0]
    else:  # HG at |g| = 1 is a delta (straight on or straight back): the set's nearest direction takes it all
        p = np.zeros_like(mu)
        p[np.argmax(mu * g)] = 1.0
    return p / p.mean()


@njit(parallel=True, cache=True)
def _gather(ext, emit, mat, pm, dirs, nodes, t_min, out):  # pragma: no cover - compiled
    """out[n, c] = sum over directions m of the radiance arriving at node ``nodes[n]`` along dirs[m] (eq. 3).

    ext (nx, ny, nz): extinction per lattice spacing; emit (nx, ny, nz, C): (sigma_s/sigma_t) power / 4 pi;
    pm (nmat, C, M): the phase on the set; the march runs from the node centre along -dirs[m].
    """
    nx, ny, nz = ext.shape
    C = emit.shape[3]
    M = dirs.shape[0]
    for n in prange(nodes.shape[0]):
        i0, j0, k0 = nodes[n, 0], nodes[n, 1], nodes[n, 2]
        acc = np.zeros(C)
        for m in range(M):
            dx, dy, dz = -dirs[m, 0], -dirs[m, 1], -dirs[m, 2]
            ox, oy, oz = i0 + 0.5, j0 + 0.5, k0 + 0.5
            i, j, k = i0, j0, k0
            tx, ty, tz = _next_boundary(i, ox, dx), _next_boundary(j, oy, dy), _next_boundary(k, oz, dz)
            sx = 1 if dx > 0.0 else -1
            sy = 1 if dy > 0.0 else -1
            sz = 1 if dz > 0.0 else -1
            t = 0.0
            trans = 1.0
            while True:
                tn = min(tx, min(ty, tz))
                e = ext[i, j, k]
                if e > 0.0 and tn > t:  # empty cells (most of a tree's box) neither emit nor attenuate
                    el = e * (tn - t)
                    a = math.exp(-el)
                    w = trans * ((tn - t) if el < 1e-8 else (1.0 - a) / e)
                    mt = mat[i, j, k]
                    for c in range(C):
                        acc[c] += w * emit[i, j, k, c] * pm[mt, c, m]
                    trans *= a
                    if trans < t_min:
                        break
                t = tn
                if tx <= ty and tx <= tz:
                    i += sx
                    if i < 0 or i >= nx:
                        break
                    tx = _next_boundary(i, ox, dx)
                elif ty <= tz:
                    j += sy
                    if j < 0 or j >= ny:
                        break
                    ty = _next_boundary(j, oy, dy)
                else:
                    k += sz
                    if k < 0 or k >= nz:
                        break
                    tz = _next_boundary(k, oz, dz)
        for c in range(C):
            out[n, c] = acc[c]


def once_scattered_energy(ext: np.ndarray, emission: np.ndarray, mat: np.ndarray, beam: np.ndarray,
                          media: list, nodes: np.ndarray, directions: int = DEFAULT_DIRECTIONS) -> np.ndarray:
    """u_1 (eq. 3) at ``nodes`` (N, 3) int: (N, C) once-scattered scalar irradiance of one unit beam.

    ``ext`` (nx, ny, nz) extinction per lattice spacing (shared by the channels), ``emission`` (nx, ny, nz, C)
    the power scattered per unit volume, (sigma_s / sigma_t) x ``lb.BeamFields.power``, ``mat`` (nx, ny, nz)
    the material index into ``media`` (``collision.Medium``: their g and phase per channel), ``beam`` the
    unit direction the beam travels.
    """
    ext = np.ascontiguousarray(ext, dtype=np.float64)
    emission = np.ascontiguousarray(emission, dtype=np.float64)
    if not (np.all(np.isfinite(ext)) and np.all(ext >= 0) and np.all(np.isfinite(emission))):
        raise ValueError("the extinction and emission must be finite and the extinction non-negative")
    dirs = fibonacci_directions(directions)
    d = np.asarray(beam, dtype=np.float64)
    d = d / np.linalg.norm(d)
    C = emission.shape[3]
    pm = np.array([[_phase_on(dirs, d, m.g[c], m.phase) for c in range(C)] for m in media])
    out = np.zeros((nodes.shape[0], C))
    _gather(ext, emission / (4.0 * math.pi), np.ascontiguousarray(mat, dtype=np.intp), pm, dirs,
            np.ascontiguousarray(nodes, dtype=np.int64), T_MIN, out)
    return out * (4.0 * math.pi / directions)


def corrected_energy(problem, result, *, directions: int | None = None, mask: np.ndarray | None = None,
                     fill: np.ndarray | None = None) -> np.ndarray:
    """Eq. (1) for every beam right-hand side of an ``lb.solve`` result: (nx, ny, nz, K, C) energy density.

    The correction u_1 - u_lattice,1 is computed at the nodes of ``mask`` (default: every node); the
    nodes of ``fill`` outside it (e.g. the empty neighbours of occupied nodes, which trilinear
    interpolation at a leaf also reads) take the mean correction of their computed 26-neighbours;
    every other node keeps the lattice's value. Other right-hand sides are returned unchanged.
    """
    from scipy import ndimage

    from foliage_tools.lighting.lb import EXT_MAX

    directions = DEFAULT_DIRECTIONS if directions is None else directions
    energy = np.array(result.energy_density, dtype=np.float64)
    if result.once_scattered is None:
        return energy
    mask = np.ones(problem.shape, bool) if mask is None else np.asarray(mask, bool)
    nodes = np.argwhere(mask)
    if nodes.size == 0:
        return energy
    media = [problem.medium]
    mat = np.zeros(problem.shape, np.intp)
    if problem.brown_mask is not None and problem.brown_mask.any():
        media.append(problem.brown_medium)
        mat[problem.brown_mask] = 1
    sig_t = np.array([m.sigma_t for m in media])  # (nmat, C)
    sig_s = np.array([m.sigma_s for m in media])
    albedo = np.divide(sig_s, sig_t, out=np.zeros_like(sig_s), where=sig_t > 0)[mat]  # (nx, ny, nz, C)
    sel = tuple(nodes.T)
    cube = np.ones((3, 3, 3))
    count = ndimage.convolve(mask.astype(np.float64), cube, mode="constant")
    filled = np.zeros(problem.shape, bool) if fill is None else (np.asarray(fill, bool) & ~mask & (count > 0))
    delta = np.zeros(problem.shape)
    for k, b in enumerate(problem.boundaries):
        if b.beam is None:
            continue
        # channels sharing sigma_t share one march (leaf media: sigma_t = 1 in every channel)
        for key in {tuple(sig_t[:, c]) for c in range(problem.channels)}:
            chans = [c for c in range(problem.channels) if tuple(sig_t[:, c]) == key]
            with np.errstate(divide="ignore"):
                ext = -np.log(np.clip(1.0 - problem.density * np.asarray(key)[mat], 0.0, None))
            ext = np.minimum(ext, EXT_MAX)
            emission = albedo[..., chans] * result.beam_power[..., k, chans]
            sub = [type(m)(sigma_a=tuple(m.sigma_a[c] for c in chans), sigma_s=tuple(m.sigma_s[c] for c in chans),
                           g=tuple(m.g[c] for c in chans), phase=m.phase) for m in media]
            u1 = once_scattered_energy(ext, emission, mat, np.asarray(b.beam), sub, nodes, directions)
            for j, c in enumerate(chans):
                delta[:] = 0.0
                delta[sel] = u1[:, j] - result.once_scattered[sel + (k, c)]
                if filled.any():
                    # the neighbours' mean correction, but never more than the lattice's own once-scattered light
                    # there: the exact u_1 is >= 0, so u_1 - u_lattice,1 >= -u_lattice,1 (without this bound a filled
                    # node beside leaves the lattice over-lit went negative: sapling 48^3, lbSun down to -4.96e-3)
                    mean = ndimage.convolve(delta, cube, mode="constant")[filled] / count[filled]
                    delta[filled] = np.maximum(mean, -result.once_scattered[..., k, c][filled])
                energy[..., k, c] += delta
    return energy
