"""Voxelize triangle soups onto an axis-aligned grid.

Two density estimators for the ``foliage density`` stage:

* :func:`area_per_voxel` -- the exact area of the triangles inside each voxel
  (polygon clipping), so that ``sum(area) == total triangle area``.
* :func:`subgrid_coverage` -- the heuristic of geist2008 sec. 4.2: every voxel
  is split into 3x3x3 sub-cubes, and its density is the fraction of sub-cubes
  that some triangle intersects (exact triangle/box overlap test).

Pure numpy + numba; no USD, no file I/O.

Index space
-----------
The kernels work in *index space* ``u = (p - origin) / voxel_size`` in which
voxel ``(i, j, k)`` is the unit cube ``[i, i+1] x [j, j+1] x [k, k+1]`` and all
voxel faces lie on integer planes (the subgrid kernel scales this by 3 so that
sub-cube faces are on integer planes). Every comparison against a face is made
on these transformed coordinates, so the assignment of geometry to voxels is
consistent between the binning and the clipping.

Boundary conventions
--------------------
``area_per_voxel``: on each axis voxel ``i`` owns the half-open slab
``[i, i+1)``, except the last voxel, which also owns the upper face of the grid.
This only matters for a polygon lying *exactly in* a face plane (any other
contact with a face has zero area): it is counted once, in the voxel on the
``+`` side of the face (or in the last voxel for the grid's upper face).

``subgrid_coverage``: sub-cubes are *closed* boxes, as in Akenine-Möller's
triangle/box test (touching counts as overlap). A triangle lying exactly in a
sub-cube face therefore marks the sub-cubes on both sides of it, and a triangle
edge lying exactly in a face marks the neighbour as well.

Zero-area triangles contribute to neither estimator (``area_per_voxel``
computes their area, exactly 0 or round-off; ``subgrid_coverage`` skips
triangles whose area is below ``1e-12 / 2`` of their squared longest edge).

Threading
---------
Both kernels are ``numba.njit(parallel=True)``. Thread ``t`` of ``T`` owns the
voxel x-slabs ``i`` with ``i % T == t``: every thread scans all triangles and
clips each one only against its own slabs, so threads never write the same
voxel (no races, no per-thread copies of the grid) and the round-robin
assignment balances the load for any smooth distribution of leaves.

Modules
-------
* ``grid`` -- :class:`GridSpec`, :func:`grid_for_bounds`, and where trilinear
  interpolation of a node field reads (:func:`trilinear_stencil`,
  :func:`stencil_mask`);
* ``clipping`` -- the polygon clipping in index space: a triangle cut into its
  voxel pieces (the loop :func:`~foliage_tools.geometry.voxelize.clipping.make_piece_walker`
  makes, shared with the own-leaf kernel of :mod:`foliage_tools.lighting.depth`)
  and the ``area_per_voxel`` kernel that adds up their areas ("Boundary
  conventions", "Threading");
* ``subgrid`` -- the ``subgrid_coverage`` kernel: the exact triangle/box
  overlap test and the 3x3x3 sub-cube marks;
* ``estimators`` -- the public functions: input checks, running a kernel on
  all threads, :func:`area_per_voxel`, :func:`subgrid_coverage` and
  :func:`mark_wood_fraction`.
"""

from __future__ import annotations

from foliage_tools.geometry.voxelize.clipping import CLIP_CAP as CLIP_CAP
from foliage_tools.geometry.voxelize.clipping import clip_slab as clip_slab
from foliage_tools.geometry.voxelize.clipping import coord_range as coord_range
from foliage_tools.geometry.voxelize.clipping import owned_range as owned_range
from foliage_tools.geometry.voxelize.clipping import projected_area as projected_area
from foliage_tools.geometry.voxelize.clipping import projection_axes as projection_axes
from foliage_tools.geometry.voxelize.estimators import area_per_voxel, mark_wood_fraction, subgrid_coverage
from foliage_tools.geometry.voxelize.grid import GridSpec, grid_for_bounds
from foliage_tools.geometry.voxelize.grid import stencil_mask as stencil_mask
from foliage_tools.geometry.voxelize.grid import trilinear_stencil as trilinear_stencil

# the private part that tests/unit/test_voxelize.py reaches as ``voxelize._tri_box_overlap`` (re-exported so that
# it keeps working; the code itself imports it from its module)
from foliage_tools.geometry.voxelize.subgrid import _tri_box_overlap as _tri_box_overlap

__all__ = ["GridSpec", "area_per_voxel", "grid_for_bounds", "mark_wood_fraction", "subgrid_coverage"]
