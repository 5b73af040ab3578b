"""Level of detail for the previewer: simplified wood, thinned leaves for far instances.

``--lod FRACTION`` draws each prototype at one of three levels:

* level 0 -- full detail (no LOD);
* level 1 (every instance nearer than ``far`` prototype radii from the camera) --
  wood meshes simplified to about FRACTION of their triangles by quadric edge
  collapse (``fast_simplification``, Garland-Heckbert error metric); leaves as they are;
* level 2 (instances farther than that) -- wood at FRACTION² of its triangles,
  and only a FRACTION of the leaves, each kept leaf scaled about its centroid by
  1/√FRACTION so the total leaf area (and with it the crown's coverage and
  optical thickness) is kept on average.

Low-poly branches (closed prisms of a few sides, as in ``examples/tree_small.usda``)
cannot be simplified by edge collapse: every collapse of a thin prism makes a
flipped or sliver triangle, which fast_simplification refuses, so it returns
them unchanged. At level 2 such wood is pruned instead: its connected parts
(branches) are kept largest-first by surface area up to FRACTION² of the
triangles -- the thin twigs that go are below a pixel at that distance. At
level 1 unsimplifiable wood stays as it is.

Leaves are never decimated: a leaf card of two triangles has nothing to
collapse, so edge collapse would only delete or distort whole leaves. A
"leaf" is a connected set of triangles (welded by position); which leaves are
kept is a fixed pseudo-random choice per prototype, so frames agree. Per-corner
data (baked E_scattered, s_max) follows the kept triangles unchanged: a leaf's
lighting is a property of where it sits in the crown, which does not move.

Simplified meshes are cached per (prototype, mesh, level) in a :class:`LodCache`
so a sequence or several cameras pay for each simplification once. The split
of instances between levels is made for one camera position (the first frame's).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from foliage_tools.errors import UsageError
from foliage_tools.geometry.sun import to_prototype_space
from foliage_tools.preview.renderer import DrawMesh, DrawPrototype, DrawScene

LEVELS = (0, 1, 2)
DEFAULT_FAR_RADII = 8.0
"""Instances farther from the camera than this many prototype bounding radii are "far" (level 2):
a crown then spans less than about 2 atan(1/8) = 14° of the view."""
LEAF_SEED = 20250401
"""Seed of the fixed choice of the leaves kept at level 2."""


@dataclass(frozen=True)
class LodParams:
    fraction: float
    """Kept share of wood triangles (level 1; squared at level 2) and of far leaves, in (0, 1]."""
    far_radii: float = DEFAULT_FAR_RADII
    """Distance, in prototype bounding radii, beyond which an instance is drawn at level 2."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.fraction) and 0.0 < self.fraction <= 1.0):
            raise UsageError(f"--lod must be a fraction in (0, 1], e.g. 0.25 (keep a quarter of the triangles); got {self.fraction:g}.")
        if not (math.isfinite(self.far_radii) and self.far_radii > 0.0):
            raise UsageError(f"the LOD distance must be a positive number of prototype radii, got {self.far_radii:g}.")


def weld(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Un-indexed (3T, 3) corners -> (points (P, 3) float64, triangles (T, 3) int64), equal positions merged."""
    c = np.asarray(corners, dtype=np.float64).reshape(-1, 3)
    points, inverse = np.unique(c, axis=0, return_inverse=True)
    return points, inverse.reshape(-1, 3).astype(np.int64)


def simplify_wood(corners: np.ndarray, fraction: float) -> np.ndarray:
    """(3T', 3) float32 corners of the mesh simplified to about ``fraction`` of its triangles (fast_simplification).

    Quadric edge collapse keeps the shape of branches and trunks where a few
    triangles can stand for many; triangles that collapse to zero area are dropped.
    """
    try:
        import fast_simplification
    except ImportError as exc:  # pragma: no cover - an install problem, named for the user
        raise UsageError(
            "--lod needs the fast-simplification package (pip install fast-simplification); it is missing from this Python."
        ) from exc
    points, tris = weld(corners)
    if fraction >= 1.0 or len(tris) < 8:
        return np.asarray(corners, dtype=np.float32).reshape(-1, 3)
    new_points, new_tris = fast_simplification.simplify(points, tris.astype(np.int32), target_reduction=1.0 - fraction)
    out = np.asarray(new_points, dtype=np.float64)[np.asarray(new_tris, dtype=np.int64)]
    area = np.linalg.norm(np.cross(out[:, 1] - out[:, 0], out[:, 2] - out[:, 0]), axis=1)
    return out[area > 0].reshape(-1, 3).astype(np.float32)


def prune_wood(corners: np.ndarray, fraction: float) -> np.ndarray:
    """(3T', 3) float32: the largest connected parts (by area) holding at most ``fraction`` of the triangles (at least one part)."""
    c = np.asarray(corners, dtype=np.float32).reshape(-1, 3)
    if fraction >= 1.0 or not len(c):
        return c
    part = leaf_components(c)
    tri = c.reshape(-1, 3, 3).astype(np.float64)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    part_area = np.bincount(part, weights=area)
    part_tris = np.bincount(part)
    order = np.argsort(-part_area, kind="stable")
    budget = fraction * len(tri)
    kept = order[: max(1, int(np.searchsorted(np.cumsum(part_tris[order]), budget, side="right")))]
    keep = np.isin(part, kept)
    return np.ascontiguousarray(tri[keep].reshape(-1, 3), dtype=np.float32)


def reduce_wood(corners: np.ndarray, fraction: float, *, prune: bool) -> np.ndarray:
    """Wood at about ``fraction`` of its triangles: edge collapse, then (``prune``) dropping the smallest parts if that fell short."""
    out = simplify_wood(corners, fraction)
    target = fraction * (len(corners) // 3)
    if prune and len(out) // 3 > 1.5 * target:
        out = prune_wood(out, target / max(len(out) // 3, 1))
    return out


def leaf_components(corners: np.ndarray) -> np.ndarray:
    """(T,) int64 leaf index of each triangle: connected components of the welded triangles."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    points, tris = weld(corners)
    if not len(tris):
        return np.zeros(0, np.int64)
    rows = np.concatenate([tris[:, 0], tris[:, 1]])
    cols = np.concatenate([tris[:, 1], tris[:, 2]])
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(points), len(points)))
    _, label = connected_components(graph, directed=False)
    return label[tris[:, 0]].astype(np.int64)


def thin_leaves(mesh: DrawMesh, fraction: float, seed: int = LEAF_SEED) -> DrawMesh:
    """Keep a ``fraction`` of the leaves, each scaled by 1/√fraction about its centroid (area kept on average)."""
    if fraction >= 1.0 or not mesh.triangle_count:
        return mesh
    leaf = leaf_components(mesh.corners)
    n_leaves = int(leaf.max()) + 1
    keep_leaf = np.random.default_rng(seed).random(n_leaves) < fraction
    if not keep_leaf.any():
        keep_leaf[np.random.default_rng(seed).integers(n_leaves)] = True  # never an empty crown
    keep = np.repeat(keep_leaf[leaf], 3)  # per corner
    corners = np.asarray(mesh.corners, dtype=np.float64)
    # centroid of each leaf (mean of its corners), then scale about it
    sums = np.zeros((n_leaves, 3))
    np.add.at(sums, np.repeat(leaf, 3), corners)
    counts = np.bincount(np.repeat(leaf, 3), minlength=n_leaves)[:, None]
    centre = (sums / np.maximum(counts, 1))[np.repeat(leaf, 3)]
    scaled = centre + (corners - centre) / math.sqrt(fraction)
    return DrawMesh(
        corners=scaled[keep].astype(np.float32),
        leaf=True,
        indirect={k: v[keep] for k, v in mesh.indirect.items()},
        smax=None if mesh.smax is None else mesh.smax[keep],
        lb_bases=None if mesh.lb_bases is None else mesh.lb_bases[:, keep],
    )


@dataclass
class LodCache:
    """Simplified meshes per (prototype index, mesh index, level, fraction)."""

    meshes: dict[tuple[int, int, int, float], DrawMesh] = field(default_factory=dict)

    def mesh(self, proto_index: int, mesh_index: int, mesh: DrawMesh, level: int, fraction: float) -> DrawMesh:
        key = (proto_index, mesh_index, level, fraction)
        if key not in self.meshes:
            if level == 0:
                out = mesh
            elif mesh.leaf:
                out = mesh if level == 1 else thin_leaves(mesh, fraction)
            else:
                out = replace(mesh, corners=reduce_wood(mesh.corners, fraction if level == 1 else fraction**2, prune=level == 2))
            self.meshes[key] = out
        return self.meshes[key]


def prototype_radius(proto: DrawPrototype) -> float:
    """Bounding radius of the prototype's geometry about its box centre, in its own units."""
    pts = np.concatenate([m.corners for m in proto.meshes]).astype(np.float64)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    return max(float(np.linalg.norm(hi - lo)) / 2, 1e-9)


def instance_levels(proto: DrawPrototype, camera_position: np.ndarray, far_radii: float) -> np.ndarray:
    """(N,) level (1 or 2) of each instance: 2 when its bounding centre is farther than ``far_radii`` world radii."""
    pts = np.concatenate([m.corners for m in proto.meshes]).astype(np.float64)
    centre = (pts.min(axis=0) + pts.max(axis=0)) / 2
    t = proto.transforms
    world_centre = np.einsum("nij,j->ni", t[:, :3, :3], centre) + t[:, :3, 3]
    # the largest stretch of each instance's linear part scales the radius
    scale = np.linalg.norm(t[:, :3, :3], ord=2, axis=(1, 2))
    dist = np.linalg.norm(world_centre - np.asarray(camera_position, dtype=np.float64), axis=1)
    return np.where(dist > far_radii * prototype_radius(proto) * scale, 2, 1)


def apply_lod(scene: DrawScene, camera_position: np.ndarray, params: LodParams, cache: LodCache | None = None) -> DrawScene:
    """The scene with each prototype split into its near (level 1) and far (level 2) instances."""
    cache = cache if cache is not None else LodCache()
    protos = []
    for i, proto in enumerate(scene.prototypes):
        if not len(proto.transforms) or not proto.meshes:
            continue
        levels = instance_levels(proto, camera_position, params.far_radii)
        for level in (1, 2):
            sel = levels == level
            if not sel.any():
                continue
            meshes = tuple(cache.mesh(i, j, m, level, params.fraction) for j, m in enumerate(proto.meshes))
            # the ω_j of s_max stay those of the whole prototype's first instance (as baked)
            smax_up = proto.smax_up if proto.smax_up is not None else to_prototype_space(np.asarray(scene.up, dtype=np.float64), proto.transforms[0])
            protos.append(replace(proto, meshes=tuple(m for m in meshes if m.triangle_count), transforms=proto.transforms[sel], smax_up=smax_up))
    return DrawScene(prototypes=tuple(protos), up=scene.up)
