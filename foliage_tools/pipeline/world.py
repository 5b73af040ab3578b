"""The whole scene in world space: every instance's triangles, with global leaf ids.

Used by methods that trace the actual geometry (the Monte Carlo reference):
leaf ``k`` of instance ``n`` of prototype ``p`` gets the global id
``offsets[n] + k``.

A forest too large to copy (more than :data:`WORLD_MAX_TRIANGLES` placed
triangles) is traced as its lone trees instead (:func:`bake_world`): one
instance per prototype, its first, each traced alone (:func:`lone_parts`),
so the shadow rays and the gather cost what the prototypes cost, not the
instances; the stand's effect on each instance then comes from the coarse
forest lattice (``pipeline.forest``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import cast

import numpy as np

from foliage_tools.scene.model import Instance, Scene


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
    triangle_offsets: np.ndarray | None = None
    """(N + 1,) first triangle of each instance."""
    lone: bool = False
    """The scene's lone trees (:func:`lone_trees`), not its instances: instance n here is its prototype's first
    instance, to be traced alone (:func:`lone_parts`)."""

    def instance_slice(self, n: int) -> slice:
        return slice(int(self.offsets[n]), int(self.offsets[n + 1]))


#: Most placed triangles the bakes copy into one world (~760 B each with Embree's scene, pipeline.plan: ~6 GB); a
#: larger forest is traced as its lone trees (module docstring). 8M is a stand of ~2 000 trees of 4 000 triangles.
WORLD_MAX_TRIANGLES = 8_000_000


def world_triangles(scene: Scene) -> int:
    """Triangles of every instance placed in the world (what :func:`assemble` copies)."""
    per_proto = [sum(len(m.triangles) for m in p.meshes) for p in scene.prototypes]
    return int(sum(per_proto[i.prototype] for i in scene.instances))


def lone_trees(scene: Scene) -> Scene:
    """The scene with one instance per instanced prototype, its first (so it sees the sun as that one does)."""
    firsts: dict[int, Instance] = {}
    for inst in scene.instances:
        firsts.setdefault(inst.prototype, inst)
    return replace(scene, instances=tuple(firsts[p] for p in sorted(firsts)))


def lone_parts(world: World) -> list[tuple[slice, slice]]:
    """Per tree the (triangle, leaf) slices to trace alone: each instance of a lone world, or the whole world."""
    if not world.lone:
        return [(slice(0, len(world.triangles)), slice(0, int(world.offsets[-1])))]
    # None only for a world without triangles (assemble), which has no instances to index it with below
    t = cast(np.ndarray, world.triangle_offsets)
    return [(slice(int(t[n]), int(t[n + 1])), world.instance_slice(n)) for n in range(len(world.instance_prototype))]


def traced_parts(world: World):
    """Per tree to trace alone (:func:`lone_parts`): its triangles, their leaf ids from 0, its leaf count and its
    slice of the world's leaves."""
    for tris, leaves in lone_parts(world):
        ids = world.leaf_of_triangle[tris]
        yield world.triangles[tris], np.where(ids >= 0, ids - leaves.start, -1), leaves.stop - leaves.start, leaves


def traced_alone(scene: Scene, triangles: int | None = None) -> bool:
    """Whether the bakes trace the scene as its lone trees: several instances placing more than
    :data:`WORLD_MAX_TRIANGLES` (``triangles``: :func:`world_triangles` of the scene, if already counted)."""
    if len(scene.instances) < 2:
        return False
    return (world_triangles(scene) if triangles is None else triangles) > WORLD_MAX_TRIANGLES


def bake_world(scene: Scene) -> World:
    """The world the bakes trace: the whole scene, or its lone trees above :data:`WORLD_MAX_TRIANGLES`."""
    if traced_alone(scene):
        return replace(assemble(lone_trees(scene)), lone=True)
    return assemble(scene)


def assemble(scene: Scene) -> World:
    tris, leaf_ids, centers = [], [], []
    offsets, tri_offsets = [0], [0]
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
        tri_offsets.append(tri_offsets[-1] + sum(len(mesh.triangles) for mesh in proto.meshes))
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
        triangle_offsets=np.array(tri_offsets, dtype=np.int64),
    )


def prototype_means(world: World, per_leaf: np.ndarray, n_prototypes: int, leaves_per_prototype: list[int]) -> list[np.ndarray]:
    """Per prototype, the mean over its instances of a per-global-leaf array (zeros for uninstanced prototypes)."""
    out = [np.zeros((n,) + per_leaf.shape[1:]) for n in leaves_per_prototype]
    counts = [0] * n_prototypes
    for n, p in enumerate(world.instance_prototype):
        out[p] += per_leaf[world.instance_slice(n)]
        counts[p] += 1
    return [o / c if c else o for o, c in zip(out, counts)]


def prototype_geometry(scene: Scene) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Per prototype, its triangles in its own frame and their leaf ids within it (-1 for wood), in the order
    :func:`assemble` places them."""
    tris, leaves = [], []
    for proto in scene.prototypes:
        t, ids = [], []
        for mesh_index, mesh in enumerate(proto.meshes):
            t.append(mesh.triangle_vertices())
            if mesh.is_leaf:
                ids.append(proto.leaves.face_leaf_ids[mesh_index][mesh.face_of_triangle])
            else:
                ids.append(np.full(len(mesh.triangles), -1, dtype=np.int64))
        tris.append(np.concatenate(t) if t else np.zeros((0, 3, 3)))
        leaves.append(np.concatenate(ids).astype(np.int64) if ids else np.zeros(0, np.int64))
    return tris, leaves


def placed_prototypes(scene: Scene) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray, np.ndarray]:
    """The scene as placements, nothing copied: :func:`prototype_geometry`, (N, 4, 4) instance transforms and
    (N,) their prototypes."""
    tris, leaves = prototype_geometry(scene)
    transforms = np.array([i.transform for i in scene.instances], dtype=np.float64).reshape(-1, 4, 4)
    return tris, leaves, transforms, np.array([i.prototype for i in scene.instances], dtype=np.int64)


def pooled_leaf_offsets(scene: Scene) -> np.ndarray:
    """(P + 1,) first leaf of each prototype when its leaves are pooled over its instances (last: the total)."""
    return np.concatenate([[0], np.cumsum([p.leaves.count for p in scene.prototypes])]).astype(np.int64)
