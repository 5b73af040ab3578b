"""Plain data read from a stage: numpy arrays in dataclasses, no ``pxr``.

Conventions
-----------
* Lengths are in the stage's units; ``Scene.meters_per_unit`` converts.
* Prototype geometry is in the prototype's own space (the space of its root
  prim, root transform included for point-instancer prototypes). An
  :class:`Instance` places it in the world with a 4×4 matrix in the
  column-vector convention: ``p_world = M @ [x, y, z, 1]``.
* Triangles index ``points``; ``face_of_triangle`` maps each triangle back to
  the authored face it came from, so per-face outputs (``uniform`` primvars)
  can be written in the authored face order.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class MeshPart:
    """One authored mesh of a prototype, triangulated."""

    path: str
    """Prim path of the mesh (inside the prototype for native instances)."""
    points: np.ndarray
    """(V, 3) float64 vertex positions in prototype space, stage units."""
    triangles: np.ndarray
    """(T, 3) int64 vertex indices."""
    face_of_triangle: np.ndarray
    """(T,) int64 index of the authored face each triangle came from."""
    face_count: int
    """Number of authored faces (length of a ``uniform`` primvar)."""
    is_leaf: bool
    """True when the mesh holds leaves (DESIGN.md section 3 rule)."""
    leaf_reason: str
    """Which rule classified it (``FoliageLeafAPI``, ``isLeaf primvar``, ``name``, ``material``, ``default``)."""
    editable: bool = True
    """False for meshes inside native instance prototypes: overs cannot be authored on them."""

    def triangle_vertices(self) -> np.ndarray:
        """(T, 3, 3) float64 vertex positions of every triangle."""
        return self.points[self.triangles]


@dataclass(frozen=True)
class Leaves:
    """Per-leaf data of a prototype: a leaf is a connected component of a leaf mesh."""

    centers: np.ndarray
    """(L, 3) float64 area-weighted centroids, stage units."""
    normals: np.ndarray
    """(L, 3) float64 unit normals (area-weighted mean of triangle normals)."""
    areas: np.ndarray
    """(L,) float64 one-sided area, stage units²."""
    mesh_index: np.ndarray
    """(L,) int64 index into ``Prototype.meshes`` of the mesh holding the leaf."""
    face_leaf_ids: tuple[np.ndarray, ...]
    """Per mesh of the prototype: (face_count,) int64 leaf id of each authored face; -1 on wood meshes and degenerate faces."""

    @property
    def count(self) -> int:
        return int(self.areas.shape[0])


@dataclass(frozen=True)
class Prototype:
    """A unique piece of tree geometry, read once however often it is instanced."""

    path: str
    """Prim path of the tree root: the prim itself, the point-instancer prototype, or the first instance of a native prototype."""
    name: str
    meshes: tuple[MeshPart, ...]
    leaves: Leaves
    kind: str
    """``prim`` (plain geometry), ``instance`` (native instanceable prototype) or ``pointinstancer``."""
    degenerate_triangles: int = 0
    """Triangles of zero area that were dropped."""

    @property
    def editable(self) -> bool:
        return self.kind != "instance"

    def triangles(self, *, leaves: bool) -> np.ndarray:
        """(T, 3, 3) float64 vertices of all leaf (or all wood) triangles."""
        parts = [m.triangle_vertices() for m in self.meshes if m.is_leaf == leaves]
        if not parts:
            return np.zeros((0, 3, 3))
        return np.concatenate(parts)

    def bounds(self, *, leaves_only: bool = False) -> np.ndarray:
        """(2, 3) min/max corner of the (leaf) geometry, stage units."""
        pts = [m.points[np.unique(m.triangles)] for m in self.meshes if m.is_leaf or not leaves_only]
        pts = [p for p in pts if len(p)]
        if not pts:
            return np.zeros((2, 3))
        allp = np.concatenate(pts)
        return np.stack([allp.min(axis=0), allp.max(axis=0)])


@dataclass(frozen=True)
class Instance:
    """One placement of a prototype in the world."""

    prototype: int
    """Index into ``Scene.prototypes``."""
    path: str
    """Instance prim path, or ``<instancer>[i]`` for point-instancer instances."""
    transform: np.ndarray
    """(4, 4) float64 world-from-prototype matrix, column-vector convention."""


@dataclass(frozen=True)
class Light:
    """A light the bakes use: the sun (``distant``) or the sky (``dome``)."""

    path: str
    kind: str
    """``distant`` or ``dome``."""
    direction: np.ndarray
    """(3,) unit vector pointing *toward* the light (for a dome: the up axis)."""
    intensity: float
    color: tuple[float, float, float]


@dataclass(frozen=True)
class Scene:
    """Everything the bakes need from a stage."""

    path: str
    up_axis: str
    """``Y`` or ``Z``."""
    meters_per_unit: float
    prototypes: tuple[Prototype, ...]
    instances: tuple[Instance, ...]
    lights: tuple[Light, ...] = field(default_factory=tuple)
    default_prim: str | None = None
    default_prim_transform: np.ndarray = field(default_factory=lambda: np.eye(4))
    """(4, 4) world-from-default-prim matrix (column-vector convention); identity without a default prim."""
    instancer_sizes: dict = field(default_factory=dict)
    """Point instancer path -> its number of instances (len(protoIndices), masked ones included): the length
    of a per-instance primvar on it."""
    empty_meshes: tuple[str, ...] = ()
    """The meshes the reader skipped for lacking points or faces, each with what it lacks (``mesh <...> has ...``)."""

    @property
    def up(self) -> np.ndarray:
        return np.array([0.0, 1.0, 0.0]) if self.up_axis == "Y" else np.array([0.0, 0.0, 1.0])

    def instances_of(self, prototype: int) -> list[Instance]:
        return [inst for inst in self.instances if inst.prototype == prototype]

    def leafy_prototypes(self) -> list[tuple[int, Prototype]]:
        """The prototypes that have leaves, with their index: what every bake computes, one at a time."""
        return [(i, p) for i, p in enumerate(self.prototypes) if p.leaves.count]
