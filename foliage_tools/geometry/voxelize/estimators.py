"""The public estimators: :func:`area_per_voxel`, :func:`subgrid_coverage` and :func:`mark_wood_fraction`.

Both estimators check their inputs and run their numba kernel (``clipping``,
``subgrid``) on all threads.
"""

from __future__ import annotations

import numba
import numpy as np

from foliage_tools.geometry.voxelize.clipping import _area_kernel
from foliage_tools.geometry.voxelize.grid import GridSpec
from foliage_tools.geometry.voxelize.subgrid import _subgrid_kernel


def _check_triangles(triangles) -> np.ndarray:
    try:
        tris = np.asarray(triangles, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"triangles must be a numeric (T, 3, 3) array of vertex positions: {exc}") from exc
    if tris.ndim != 3 or tris.shape[1:] != (3, 3):
        raise ValueError(f"triangles must have shape (T, 3, 3) (T triangles x 3 vertices x xyz), got {tris.shape}")
    finite = np.isfinite(tris).all(axis=(1, 2))
    if not finite.all():
        bad = np.flatnonzero(~finite)
        raise ValueError(
            f"triangles must be finite: {bad.size} triangle(s) hold NaN or infinite coordinates (first: index {int(bad[0])})"
        )
    return np.ascontiguousarray(tris)


def _check_grid(grid) -> GridSpec:
    if not isinstance(grid, GridSpec):
        raise TypeError(f"grid must be a GridSpec, got {type(grid).__name__}")
    return grid


def _run(kernel, triangles, grid) -> np.ndarray:
    """Check the inputs and run one of the voxel kernels on all threads (zeros for no triangles)."""
    tris = _check_triangles(triangles)
    grid = _check_grid(grid)
    nx, ny, nz = grid.shape
    if tris.shape[0] == 0:
        return np.zeros(grid.shape, dtype=np.float64)
    origin = np.asarray(grid.origin, dtype=np.float64)
    return kernel(tris, origin, grid.voxel_size, nx, ny, nz, numba.get_num_threads())


def area_per_voxel(triangles: np.ndarray, grid: GridSpec) -> np.ndarray:
    """Exact area of the triangles inside each voxel.

    Every triangle is sliced by the voxel x-planes, each piece by the y-planes,
    then the z-planes (Sutherland-Hodgman on fixed-size buffers) and the area
    of each final piece is added to its voxel, so the result partitions the
    triangles' area: ``out.sum()`` equals the total area of the triangles (to
    round-off, ~1e-15 relative) when all of them lie inside the grid. Parts of
    triangles outside the grid are dropped. A polygon lying exactly in a voxel
    face plane is counted once, in the voxel on the ``+`` side of that face (the
    last voxel for the grid's upper face). Zero-area triangles contribute 0.

    Parameters
    ----------
    triangles : array_like, shape (T, 3, 3)
        Vertex positions (stage units) of T triangles, float (converted to
        float64). T may be 0.
    grid : GridSpec
        The voxel grid.

    Returns
    -------
    numpy.ndarray, shape ``grid.shape``, float64
        Triangle area inside each voxel, stage units squared (divide by
        ``grid.voxel_volume`` for a leaf-area density in 1/stage unit).

    Raises
    ------
    ValueError
        If ``triangles`` is not (T, 3, 3) or holds non-finite coordinates.
    TypeError
        If ``grid`` is not a :class:`GridSpec`.
    """
    return _run(_area_kernel, triangles, grid)


def subgrid_coverage(triangles: np.ndarray, grid: GridSpec) -> np.ndarray:
    """Fraction of each voxel's 27 sub-cubes that the triangles intersect (geist2008 sec. 4.2).

    geist2008 sec. 4.2: "Each grid node is refined into a 3x3x3 subgrid. If any
    triangle intersects a node of the subgrid, then that subgrid node is marked
    as intersected. The density of the grid node is then the ratio of the number
    of its intersected subgrid nodes to 27." A subgrid node is taken to be the
    closed sub-cube of side ``voxel_size / 3``; intersection is decided by an
    exact triangle/box separating-axis test (Akenine-Möller), not by bounding
    boxes. Touching counts: a triangle lying exactly in a sub-cube face marks
    the sub-cubes on both sides. Zero-area triangles (twice the area
    ``<= 1e-12 * longest edge**2``: coincident or collinear vertices, up to
    round-off) mark nothing.

    Parameters
    ----------
    triangles : array_like, shape (T, 3, 3)
        Vertex positions (stage units) of T triangles, float (converted to
        float64). T may be 0.
    grid : GridSpec
        The voxel grid.

    Returns
    -------
    numpy.ndarray, shape ``grid.shape``, float64
        Dimensionless coverage in ``{0, 1/27, 2/27, ..., 1}``.

    Raises
    ------
    ValueError
        If ``triangles`` is not (T, 3, 3) or holds non-finite coordinates.
    TypeError
        If ``grid`` is not a :class:`GridSpec`.
    """
    return _run(_subgrid_kernel, triangles, grid)


def mark_wood_fraction(leaf_area: np.ndarray, wood_area: np.ndarray) -> np.ndarray:
    """Share of wood in each voxel's surface: ``wood / (leaf + wood)``, 0 where both are 0.

    Parameters
    ----------
    leaf_area, wood_area : array_like, same shape
        Non-negative, finite per-voxel amounts of leaf and wood surface, in the
        same units (areas from :func:`area_per_voxel`, or coverages from
        :func:`subgrid_coverage`).

    Returns
    -------
    numpy.ndarray, same shape, float64
        Values in ``[0, 1]``; always finite.

    Raises
    ------
    ValueError
        If the shapes differ or either input holds negative or non-finite values.
    """
    leaf = np.asarray(leaf_area, dtype=np.float64)
    wood = np.asarray(wood_area, dtype=np.float64)
    if leaf.shape != wood.shape:
        raise ValueError(f"leaf_area and wood_area must have the same shape, got {leaf.shape} and {wood.shape}")
    for name, arr in (("leaf_area", leaf), ("wood_area", wood)):
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} must be finite")
        if np.any(arr < 0.0):
            raise ValueError(f"{name} must be >= 0, got a minimum of {float(arr.min())}")
    total = leaf + wood
    out = np.zeros(leaf.shape, dtype=np.float64)
    np.divide(wood, total, out=out, where=total > 0.0)
    return out
