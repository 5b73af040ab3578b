"""The whole scene in world space: every instance's triangles, with global leaf ids.

Used by methods that trace the actual geometry (the Monte Carlo reference):
leaf ``k`` of instance ``n`` of prototype ``p`` gets the global id
``offsets[n] + k``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from foliage_tools.scene.model import Scene


@dataclass(frozen=True)
class World:
    triangles: np.ndarray
    """(T, 3, 3) float64 world-space vertices."""
    leaf_of_triangle: np.ndarray
    """(T,) int64 global leaf id, -1 for wood and degenerate triangles."""
    leaf_area: np.ndarray
    """(L,) float64 one-sided world-space area of each global leaf."""
    leaf_centers: np.ndarray
    """(L, 3) float64 world-space leaf centres (the prototypes' centres placed by each instance)."""
    instance_prototype: np.ndarray
    """(N,) prototype index of each instance (the order of ``Scene.instances``)."""
    offsets: np.ndarray
    """(N + 1,) first global leaf id of each instance; the last entry is L."""

    def instance_slice(self, n: int) -> slice:
        return slice(int(self.offsets[n]), int(self.offsets[n + 1]))


def assemble(scene: Scene) -> World:
    tris, leaf_ids, centers = [], [], []
    offsets = [0]
    for inst in scene.instances:
        proto = scene.prototypes[inst.prototype]
        m = inst.transform
        for mesh_index, mesh in enumerate(proto.meshes):
            v = mesh.triangle_vertices()
            tris.append(v @ m[:3, :3].T + m[:3, 3])
            if mesh.is_leaf:
                ids = proto.leaves.face_leaf_ids[mesh_index][mesh.face_of_triangle]
                leaf_ids.append(np.where(ids >= 0, ids + offsets[-1], -1))
            else:
                leaf_ids.append(np.full(len(v), -1, dtype=np.int64))
        centers.append(proto.leaves.centers @ m[:3, :3].T + m[:3, 3])
        offsets.append(offsets[-1] + proto.leaves.count)
    if not tris:
        z = np.zeros((0, 3, 3))
        return World(z, np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3)), np.zeros(0, np.int64), np.array([0]))
    triangles = np.concatenate(tris)
    leaf_of_triangle = np.concatenate(leaf_ids).astype(np.int64)
    cross = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    ok = leaf_of_triangle >= 0
    leaf_area = np.bincount(leaf_of_triangle[ok], weights=area[ok], minlength=offsets[-1])
    return World(
        triangles=triangles,
        leaf_of_triangle=leaf_of_triangle,
        leaf_area=leaf_area,
        leaf_centers=np.concatenate(centers),
        instance_prototype=np.array([i.prototype for i in scene.instances], dtype=np.int64),
        offsets=np.array(offsets, dtype=np.int64),
    )


def prototype_means(world: World, per_leaf: np.ndarray, n_prototypes: int, leaves_per_prototype: list[int]) -> list[np.ndarray]:
    """Per prototype, the mean over its instances of a per-global-leaf array (zeros for uninstanced prototypes)."""
    out = [np.zeros((n,) + per_leaf.shape[1:]) for n in leaves_per_prototype]
    counts = [0] * n_prototypes
    for n, p in enumerate(world.instance_prototype):
        out[p] += per_leaf[world.instance_slice(n)]
        counts[p] += 1
    return [o / c if c else o for o, c in zip(out, counts)]
