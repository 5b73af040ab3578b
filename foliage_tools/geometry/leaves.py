"""Triangulation and leaf extraction: a leaf is a connected component of a leaf mesh.

Pure numpy/scipy, vectorised over faces (no per-face Python loops).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

#: Relative tolerance (of the mesh's bounding-box diagonal) under which two
#: vertices count as the same point when finding connected leaves. Converted
#: assets often give every triangle its own vertices; welding by position
#: recovers the cards.
WELD_TOLERANCE = 1e-7

#: Triangles whose area is below this fraction of diag² are degenerate.
DEGENERATE_AREA = 1e-14


def triangulate(face_vertex_counts: np.ndarray, face_vertex_indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fan-triangulate polygons.

    Parameters
    ----------
    face_vertex_counts : (F,) int
        Vertices per face. Faces with fewer than 3 produce no triangle.
    face_vertex_indices : (sum(counts),) int

    Returns
    -------
    triangles : (T, 3) int64 vertex indices
    face_of_triangle : (T,) int64 authored face of each triangle
    """
    counts = np.asarray(face_vertex_counts, dtype=np.int64)
    indices = np.asarray(face_vertex_indices, dtype=np.int64)
    if counts.sum() != indices.shape[0]:
        raise ValueError(
            f"faceVertexCounts sum to {int(counts.sum())} but there are {indices.shape[0]} faceVertexIndices"
        )
    offsets = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    n_tri = np.maximum(counts - 2, 0)
    face_of_triangle = np.repeat(np.arange(counts.shape[0], dtype=np.int64), n_tri)
    # k = 1 .. n-2 within each face: position in the run of that face's triangles
    first_tri = np.concatenate([[0], np.cumsum(n_tri)[:-1]])
    k = np.arange(face_of_triangle.shape[0], dtype=np.int64) - first_tri[face_of_triangle] + 1
    base = offsets[face_of_triangle]
    triangles = np.stack([indices[base], indices[base + k], indices[base + k + 1]], axis=1)
    return triangles, face_of_triangle


def triangle_area_normals(points: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Area (T,) and (not normalised) area-vector (T, 3) = cross/2 of each triangle."""
    v = points[triangles]
    cross = 0.5 * np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    return np.linalg.norm(cross, axis=1), cross


@dataclass(frozen=True)
class LeafComponents:
    """Leaves of one mesh."""

    centers: np.ndarray  # (L, 3)
    normals: np.ndarray  # (L, 3) unit
    areas: np.ndarray  # (L,)
    triangle_leaf: np.ndarray  # (T,) leaf id of each triangle, -1 for degenerate ones
    degenerate: int


def leaf_components(points: np.ndarray, triangles: np.ndarray) -> LeafComponents:
    """Split a leaf mesh into leaves (connected components after welding by position).

    Parameters
    ----------
    points : (V, 3) float
    triangles : (T, 3) int

    Returns
    -------
    LeafComponents
        Centres are area-weighted centroids; normals are the area-weighted
        mean of triangle normals, each first flipped into the hemisphere of
        the leaf's largest triangle (cards authored with mixed winding would
        otherwise cancel).
    """
    points = np.asarray(points, dtype=np.float64)
    triangles = np.asarray(triangles, dtype=np.int64)
    n_tri = triangles.shape[0]
    if n_tri == 0:
        z = np.zeros((0, 3))
        return LeafComponents(z, z, np.zeros(0), np.zeros(0, dtype=np.int64), 0)
    diag = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0))) or 1.0
    area, avec = triangle_area_normals(points, triangles)
    good = area > DEGENERATE_AREA * diag * diag
    tri = triangles[good]
    # weld vertices by position, so cards whose triangles do not share indices still connect
    q = np.round(points / (WELD_TOLERANCE * diag)).astype(np.int64)
    _, welded = np.unique(q, axis=0, return_inverse=True)
    welded = welded.reshape(-1)
    n_weld = int(welded.max()) + 1
    wt = welded[tri]  # (Tg, 3)
    n_good = tri.shape[0]
    rows = np.repeat(np.arange(n_good), 3)
    graph = coo_matrix((np.ones(3 * n_good, dtype=np.int8), (rows, n_good + wt.reshape(-1))), shape=(n_good + n_weld,) * 2)
    _, labels = connected_components(graph, directed=False)
    tri_label = labels[:n_good]
    # renumber components so leaf ids follow the first triangle of each leaf
    _, first, leaf_of_good = np.unique(tri_label, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(order.shape[0])
    leaf_of_good = rank[leaf_of_good.reshape(-1)]
    n_leaves = order.shape[0]

    a = area[good]
    av = avec[good]
    cen = points[tri].mean(axis=1)
    areas = np.bincount(leaf_of_good, weights=a, minlength=n_leaves)
    centers: np.ndarray = np.stack([np.bincount(leaf_of_good, weights=a * cen[:, i], minlength=n_leaves) for i in range(3)], axis=1)
    centers /= areas[:, None]
    # reference normal per leaf: that of its largest triangle
    by_leaf_then_area = np.lexsort((-a, leaf_of_good))
    firsts = np.searchsorted(leaf_of_good[by_leaf_then_area], np.arange(n_leaves))
    ref = av[by_leaf_then_area[firsts]]
    sign = np.where(np.einsum("ij,ij->i", av, ref[leaf_of_good]) < 0.0, -1.0, 1.0)
    nsum = np.stack([np.bincount(leaf_of_good, weights=sign * av[:, i], minlength=n_leaves) for i in range(3)], axis=1)
    normals = nsum / np.linalg.norm(nsum, axis=1, keepdims=True)

    triangle_leaf = np.full(n_tri, -1, dtype=np.int64)
    triangle_leaf[good] = leaf_of_good
    return LeafComponents(centers, normals, areas, triangle_leaf, int(n_tri - n_good))


def face_values_from_triangles(face_of_triangle: np.ndarray, triangle_values: np.ndarray, face_count: int, fill: int = -1) -> np.ndarray:
    """Per authored face, the value of its first triangle whose value is not ``fill``."""
    out = np.full(face_count, fill, dtype=np.int64)
    keep = triangle_values != fill
    # reversed assignment so the first triangle of each face wins
    f = face_of_triangle[keep][::-1]
    out[f] = triangle_values[keep][::-1]
    return out
