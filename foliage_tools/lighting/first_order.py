"""Once-scattered sun light per leaf from the leaves' exact direct light, marched through a coarse voxel medium.

Why
---
SPPG's first order of scattering is the plane-parallel slab's at the leaf's
depths times G (shinya2013 eqs. 23-28). Split by order against the Monte
Carlo reference (the paper's setting: zenith sun, r = t = 0.475), the slab's
first order is wrong in a way G cannot mend: its ratio to the reference's
once-scattered light runs 1.12 -> 1.99 from the top to the bottom fifth of
the oak by depth, while G is nearly constant over depth (0.72-0.77). A slab
around each leaf has no lateral edges, so the light the crown above scatters
sideways out of a finite crown stays in the slab; and the slab lights its
scatterers with the mean transmission of a layer, not with the leaves' own
lit fractions (issue #15 notes).

What is computed
----------------
The first-collision source of transport theory with the exact direct light:
leaf triangle k (area A_k, unit normal n_k, leaf direct irradiance E_k of its
lit face, from the shadow rays every bake traces) sends intensity

    I_k(w) = E_k A_k |n_k . w| c_k(w) / pi                                (1)

toward w, c_k = r on the lit side (sign(n_k . w) = sign(n_k . sun)) and t on
the other: a two-sided Lambertian leaf, whose scattered power over the sphere
is E_k A_k (r + t). Wood is opaque Lambertian (the reference's): a wood
triangle with direct irradiance E_k (``wood_direct``, its own shadow rays)
sends eq. (1) with c_k = rho_wood on its lit side and 0 on the other. Per
voxel of a grid of ``resolution`` voxels along the longest edge, the emission
per unit volume and the extinction coefficient along w are

    J(w) = sum_k I_k(w) / V,    sigma(w) = sum_k a_k A_k |n_k . w| / V   (2)

(a_k = 1 for a leaf, 1/2 for wood: the projection of a closed surface is half
the sum of its triangles'). A leaf's
once-scattered irradiance, both faces summed, is

    E1_i = sum_m (4 pi / M) (sum_{k in i} A_k |n_k . w_m| / A_i) L_m,    (3)
    L_m  = int_0^inf J(x_i + s w_m, -w_m) exp(-tau(x_i, x_i + s w_m)) ds,

over M directions (``single_scatter.fibonacci_directions``), the s-integral
exact per voxel segment (J (1 - e^{-sigma l}) / sigma, the medium constant
per voxel, marched cell by cell after Amanatides & Woo 1987) until the
transmittance falls below ``T_MIN``. The leaf's own triangles are taken out
of J and sigma in the voxel the march starts in, so a leaf neither lights
nor shades itself.

Averaged shifted grids
----------------------
A leaf's first order through one voxel grid depends on where the cell
boundaries fall around it and its neighbours (which lit leaves share its cell
and are taken as a uniform medium, which lie one cell over): an aliasing noise
of the deposit, leaf by leaf, that no choice of one grid removes. Averaging the
march over copies of the grid with the inner boundaries moved by half a cell is
the averaged shifted histogram of density estimation (Scott 1985, Ann. Stat.
13(3), 1024): the mean of the shifted piecewise-constant media is a smoother
estimate of the leaf-area and emission densities, and the mean of the
once-scattered light through them averages the aliasing out. The shifted
copies keep the box's faces as boundaries (their first and last cells are
(1 - s) h and s h long, ``_shifted_edges``), so the layer's faces stay on cell
boundaries. ``shifts`` = 2 (the fitted grid and its copy moved by h/2 along
every axis) by default; measured in README "SPPG's first order".

SPPG keeps its law for the later orders (``gfactor``, "Orders of
scattering"): E = E1 / (1 - (1 - s) rho), with s the slab's once-scattered
share and rho the recollision ratio at the leaf (``SPPGResult.orders``).
Measured in README "SPPG's first order".
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from foliage_tools.lighting.optics import LeafOptics
from foliage_tools.lighting.lb.single_scatter import fibonacci_directions

__all__ = ["DEFAULT_DIRECTIONS", "DEFAULT_RESOLUTION", "DEFAULT_SHIFTS", "SHIFTS", "T_MIN", "FirstOrderInputs", "FirstOrderResult", "solve"]

#: Voxels along the longest edge of the leaves' bounding box. Against the reference's once-scattered light in the
#: paper's setting, tree_small / oak / sapling: total 0.97 / 1.01 / 1.03 at 16, 0.95 / 0.99 / 0.97 at 32 and
#: 0.91 / 0.90 / 0.93 at 64 (a voxel that holds a leaf or two no longer homogenises; README "SPPG's first order").
DEFAULT_RESOLUTION = 32
#: Grids averaged (module docstring, "Averaged shifted grids"): 1, the fitted grid alone; 2, with the copy whose
#: inner boundaries are moved by half a cell along every axis; 8, with every corner of the half-cell shift.
SHIFTS = {1: ((0.0, 0.0, 0.0),), 2: ((0.0, 0.0, 0.0), (0.5, 0.5, 0.5)),
          8: tuple((a, b, c) for a in (0.0, 0.5) for b in (0.0, 0.5) for c in (0.0, 0.5))}
DEFAULT_SHIFTS = 2
#: Directions over the sphere (``single_scatter.DEFAULT_DIRECTIONS``, the same set as LB's exact first order).
DEFAULT_DIRECTIONS = 64
#: Triangles whose (M, C) intensities are held at once.
_CHUNK = 8192
#: A march stops once the transmittance back to the leaf is below this.
T_MIN = 1e-3


@dataclass(frozen=True)
class FirstOrderInputs:
    """World-space triangles with leaf ids, the leaves and their exact direct light, the optics and the sun."""

    triangles: np.ndarray
    """(T, 3, 3) vertices of every leaf and wood triangle."""
    leaf_of_triangle: np.ndarray
    """(T,) leaf id 0..L-1, -1 for wood."""
    leaf_centers: np.ndarray
    """(L, 3) where each leaf's march starts."""
    leaf_area: np.ndarray
    """(L,) one-sided leaf area."""
    e_direct: np.ndarray
    """(L,) or (L, C) direct sun irradiance of each leaf (lit face; sun irradiance 1 perpendicular to its
    direction); one column serves every channel of ``optics``."""
    optics: LeafOptics
    sun_direction: np.ndarray
    """(3,) toward the sun."""
    wood_direct: np.ndarray | None = None
    """(W,) direct sun irradiance of each wood triangle (those with leaf id -1, in order; its lit side), which
    then scatters with ``optics.wood_reflectance`` on that side; None: wood only blocks."""

    def __post_init__(self) -> None:
        tri = np.asarray(self.triangles, dtype=np.float64)
        if tri.ndim != 3 or tri.shape[1:] != (3, 3) or not np.all(np.isfinite(tri)):
            raise ValueError(f"triangles must be finite (T, 3, 3), got {tri.shape}")
        lf = np.asarray(self.leaf_of_triangle, dtype=np.int64)
        centers = np.asarray(self.leaf_centers, dtype=np.float64)
        n = centers.shape[0]
        if lf.shape != (tri.shape[0],) or (lf.size and (lf.min() < -1 or lf.max() >= n)):
            raise ValueError(f"leaf_of_triangle must be ({tri.shape[0]},) ids in [-1, {n - 1}]")
        area = np.asarray(self.leaf_area, dtype=np.float64)
        e = np.asarray(self.e_direct, dtype=np.float64)
        e = e.reshape(n, 1) if e.ndim == 1 and e.shape[0] == n else e
        if centers.shape != (n, 3) or not np.all(np.isfinite(centers)):
            raise ValueError(f"leaf_centers must be finite (L, 3), got {centers.shape}")
        if area.shape != (n,) or not np.all(area > 0):
            raise ValueError(f"leaf_area must be ({n},) and > 0")
        if e.ndim != 2 or e.shape[0] != n or not np.all(np.isfinite(e)) or np.any(e < 0):
            raise ValueError(f"e_direct must be ({n}, C) finite and >= 0, got {e.shape}")
        if self.wood_direct is not None:
            wd = np.asarray(self.wood_direct, dtype=np.float64)
            if wd.shape != (int(np.count_nonzero(lf < 0)),) or not np.all(np.isfinite(wd)) or np.any(wd < 0):
                raise ValueError(f"wood_direct must be one finite value >= 0 per wood triangle, got {wd.shape}")
            object.__setattr__(self, "wood_direct", wd)
        sun = np.asarray(self.sun_direction, dtype=np.float64)
        if sun.shape != (3,) or not np.linalg.norm(sun) > 0:
            raise ValueError("sun_direction must be a non-zero 3-vector")
        for name, v in (("triangles", tri), ("leaf_of_triangle", lf), ("leaf_centers", centers), ("leaf_area", area),
                        ("e_direct", e), ("sun_direction", sun / np.linalg.norm(sun))):
            object.__setattr__(self, name, v)


@dataclass(frozen=True)
class FirstOrderResult:
    e_once: np.ndarray
    """(L, C) once-scattered sun irradiance per leaf, both faces summed."""
    shape: tuple[int, int, int]
    """The voxel grid's cells per axis."""
    seconds: float


@njit(parallel=True, cache=True)
def _march(edges, shape, start, sigma, emit, self_sigma, self_emit, x0, dirs, t_min, out):  # pragma: no cover - compiled
    """out[i, m, c]: eq. (3)'s L_m per channel for each leaf centre x0[i] (module docstring). ``edges`` (3, n + 1)
    the cell boundaries per axis (padded), ``start`` (L, 3) the cell each march starts in."""
    n, n_dirs, n_ch = x0.shape[0], dirs.shape[0], emit.shape[4]
    for i in prange(n):
        acc = np.empty(n_ch)
        for m in range(n_dirs):
            d0, d1, d2 = dirs[m, 0], dirs[m, 1], dirs[m, 2]
            p = np.array([x0[i, 0], x0[i, 1], x0[i, 2]])
            c = np.array([start[i, 0], start[i, 1], start[i, 2]])
            trans = 1.0
            acc[:] = 0.0
            first = True
            while c[0] >= 0 and c[1] >= 0 and c[2] >= 0 and c[0] < shape[0] and c[1] < shape[1] and c[2] < shape[2]:
                t_exit, axis = 1e300, 0
                for k in range(3):
                    dk = d0 if k == 0 else (d1 if k == 1 else d2)
                    if dk > 1e-12:
                        t = (edges[k, c[k] + 1] - p[k]) / dk
                    elif dk < -1e-12:
                        t = (edges[k, c[k]] - p[k]) / dk
                    else:
                        t = 1e300
                    if t < t_exit:
                        t_exit, axis = t, k
                seg = max(t_exit, 0.0)
                s = sigma[c[0], c[1], c[2], m]
                if first:
                    s = max(s - self_sigma[i, m], 0.0)
                # the emitted share of a segment of length seg: (1 - e^{-s seg}) / s, seg when s -> 0
                share = (1.0 - math.exp(-s * seg)) / s if s * seg > 1e-9 else seg
                for ch in range(n_ch):
                    e = emit[c[0], c[1], c[2], m, ch]
                    if first:
                        e = max(e - self_emit[i, m, ch], 0.0)
                    acc[ch] += trans * e * share
                first = False
                trans *= math.exp(-s * seg)
                if trans < t_min:
                    break
                p[0] += d0 * seg
                p[1] += d1 * seg
                p[2] += d2 * seg
                dk = d0 if axis == 0 else (d1 if axis == 1 else d2)
                c[axis] += 1 if dk > 0 else -1
            for ch in range(n_ch):
                out[i, m, ch] = acc[ch]


def _fit_grid(points: np.ndarray, resolution: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The march's grid: ``lo``, the (3,) cell edges and the cells per axis over the points' bounding box.

    The box is that of the triangle centroids (where each triangle's area and emission are deposited) and the
    leaf centres (where the marches start). The longest axis holds ``resolution`` cells of h = extent /
    resolution; every other axis at least h long holds round(extent / h) cells stretched or shrunk to fill it,
    so a face of the medium that is a face of the box (a layer's top and bottom) falls on a cell boundary: with
    cubic cells a 1.5 m layer took 5.2 cells of 0.317 m and its bottom cell was 79 % full, which diluted the
    extinction around the bottom leaves (the layer's bottom bin read +3.5 ... +6.3 % over the exact slab's first
    order, README "SPPG's first order"). An axis shorter than h (a flat or thin medium) gets one cell of h
    centred on it, which keeps the leaves' own extent (the centroids of a card span a third of it) inside.
    """
    lo = points.min(axis=0)
    extent = points.max(axis=0) - lo
    longest = float(extent.max())
    h0 = longest / resolution if longest > 0.0 else 1.0
    thin = extent < h0
    shape = np.where(thin, 1, np.rint(extent / h0)).astype(np.int64)
    h = np.where(thin, h0, extent / np.maximum(shape, 1))
    lo = np.where(thin, lo + 0.5 * extent - 0.5 * h0, lo)
    return lo - 1e-9 * h, h * (1.0 + 2e-9), shape


def _shifted_edges(lo: np.ndarray, h: np.ndarray, shape: np.ndarray, shift: tuple[float, float, float]) -> list[np.ndarray]:
    """The cell boundaries per axis of the fitted grid with its inner boundaries moved by ``shift`` x h: the box's
    faces stay boundaries, so an axis of n cells shifted by s in (0, 1) has n + 1, the first (1 - s) h and the
    last s h long (an axis of one cell is not shifted)."""
    out = []
    for k in range(3):
        n, s = int(shape[k]), float(shift[k])
        inner = lo[k] + (np.arange(1, n + 1) - s) * h[k] if 0.0 < s < 1.0 and n > 1 else lo[k] + np.arange(1, n) * h[k]
        out.append(np.concatenate([[lo[k]], inner, [lo[k] + n * h[k]]]))
    return out


def solve(inputs: FirstOrderInputs, *, resolution: int = DEFAULT_RESOLUTION, directions: int = DEFAULT_DIRECTIONS,
          shifts: int = DEFAULT_SHIFTS) -> FirstOrderResult:
    """Each leaf's once-scattered sun irradiance (module docstring, eqs. 1-3)."""
    if isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer)) or not 1 <= resolution <= 512:
        raise ValueError(f"resolution must be an integer in [1, 512], got {resolution!r}")
    if shifts not in SHIFTS:
        raise ValueError(f"shifts must be one of {sorted(SHIFTS)}, got {shifts!r}")
    start = time.perf_counter()
    tri, lf, centers, area, e_dir = (inputs.triangles, inputs.leaf_of_triangle, inputs.leaf_centers, inputs.leaf_area,
                                     inputs.e_direct)
    r = np.asarray(inputs.optics.reflectance, dtype=np.float64)
    t = np.asarray(inputs.optics.transmittance, dtype=np.float64)
    n, n_ch = e_dir.shape[0], max(e_dir.shape[1], r.size)
    if e_dir.shape[1] not in (1, n_ch):
        raise ValueError(f"e_direct has {e_dir.shape[1]} channels, the optics {r.size}")
    if n == 0:
        return FirstOrderResult(np.zeros((0, n_ch)), (0, 0, 0), 0.0)
    r, t = np.broadcast_to(r, (n_ch,)), np.broadcast_to(t, (n_ch,))
    dirs = fibonacci_directions(directions)
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    twice = np.linalg.norm(cross, axis=1)
    e_wood = np.zeros(len(tri))
    if inputs.wood_direct is not None:
        e_wood[lf < 0] = inputs.wood_direct
    keep = twice > 0.0
    tri, lf, cross, twice, e_wood = tri[keep], lf[keep], cross[keep], twice[keep], e_wood[keep]
    tri_area, normal = 0.5 * twice, cross / twice[:, None]
    centroids = tri.mean(axis=1)
    lo, h, shape = _fit_grid(np.concatenate([centroids, centers]), resolution)
    leaf = lf >= 0
    lit = np.sign(normal @ inputs.sun_direction)                            # the sunlit side of each triangle
    e_tri = np.where(leaf[:, None], e_dir[np.maximum(lf, 0)], e_wood[:, None])   # (T, C)
    wood_r = np.broadcast_to(np.asarray(inputs.optics.wood_reflectance, dtype=np.float64), (n_ch,))
    receive = np.zeros((n, len(dirs)))
    np.add.at(receive, lf[leaf], np.abs(normal[leaf] @ dirs.T) * tri_area[leaf, None])
    radiance = np.zeros((n, len(dirs), n_ch))
    out = np.empty((n, len(dirs), n_ch))
    grid_shifts = SHIFTS[shifts]
    for shift in grid_shifts:                                               # averaged shifted grids (module docstring)
        edges = _shifted_edges(lo, h, shape, shift)
        cells_per_axis = np.array([len(e) - 1 for e in edges])
        padded = np.full((3, int(cells_per_axis.max()) + 1), np.inf)
        for k in range(3):
            padded[k, : len(edges[k])] = edges[k]

        def cell_of(x: np.ndarray, edges=edges, cells_per_axis=cells_per_axis) -> np.ndarray:
            return np.stack([np.clip(np.searchsorted(edges[k], x[:, k], side="right") - 1, 0, cells_per_axis[k] - 1)
                             for k in range(3)], axis=1)

        cell = cell_of(centroids)
        flat = np.ravel_multi_index(tuple(cell.T), tuple(int(c) for c in cells_per_axis))
        volume = np.einsum("i,j,k->ijk", *(np.diff(e) for e in edges)).ravel()
        start_cell = cell_of(centers)
        own = leaf & np.all(cell == start_cell[np.maximum(lf, 0)], axis=1)  # the leaf itself, where its march starts
        cells = int(np.prod(cells_per_axis))
        sigma = np.zeros((cells, len(dirs)))
        emit = np.zeros((cells, len(dirs), n_ch))
        self_sigma = np.zeros((n, len(dirs)))
        self_emit = np.zeros((n, len(dirs), n_ch))
        for a in range(0, len(tri), _CHUNK):                                # (chunk, M, C) at a time
            b = slice(a, a + _CHUNK)
            cos = normal[b] @ dirs.T
            proj = np.abs(cos) * tri_area[b, None]
            # toward the receiver the light travels along -w_m: it leaves the emitter on the side sign(n . -w_m)
            lit_side = (np.sign(-cos) == lit[b, None])[:, :, None]
            coef = np.where(leaf[b, None, None], np.where(lit_side, r, t), np.where(lit_side, wood_r, 0.0))
            vol = volume[flat[b], None]
            intensity = e_tri[b, None, :] * proj[:, :, None] * coef / math.pi / vol[..., None]   # eq. (1) / V
            block = np.where(leaf[b, None], proj, 0.5 * proj) / vol
            np.add.at(sigma, flat[b], block)                                 # eq. (2)
            np.add.at(emit, flat[b], intensity)
            mine, ids = own[b], lf[b]
            np.add.at(self_sigma, ids[mine], block[mine])
            np.add.at(self_emit, ids[mine], intensity[mine])
        _march(padded, cells_per_axis, start_cell, sigma.reshape(*cells_per_axis, len(dirs)),
               emit.reshape(*cells_per_axis, len(dirs), n_ch), self_sigma, self_emit, centers, dirs, T_MIN, out)
        radiance += out
    radiance /= len(grid_shifts)
    e_once = np.einsum("nm,nmc->nc", receive, radiance) * (4.0 * math.pi / len(dirs)) / area[:, None]   # eq. (3)
    if not np.all(np.isfinite(e_once)):
        raise FloatingPointError("the first-order march gave non-finite irradiance (report this with the input)")
    return FirstOrderResult(e_once, (int(shape[0]), int(shape[1]), int(shape[2])), time.perf_counter() - start)
