"""Per-leaf results -> per-face ``uniform`` primvars on the leaf meshes of a prototype."""

from __future__ import annotations

import numpy as np

from foliage_tools.scene.model import Prototype, Scene
from foliage_tools.scene.write import AttributeEdit, PrimvarEdit


def per_face(proto: Prototype, mesh_index: int, per_leaf: np.ndarray) -> np.ndarray:
    """Values of each authored face of one leaf mesh: the value of its leaf (zeros for degenerate faces).

    ``per_leaf`` is (L,) or (L, k); the result is (F,) or (F, k).
    """
    ids = proto.leaves.face_leaf_ids[mesh_index]
    values = np.asarray(per_leaf)
    out = np.zeros((ids.shape[0],) + values.shape[1:], dtype=values.dtype)
    ok = ids >= 0
    out[ok] = values[ids[ok]]
    return out


def _leaf_meshes(proto: Prototype):
    """(index, mesh) of each leaf mesh of an editable prototype; none for a native-instance prototype."""
    if proto.editable:
        yield from ((i, m) for i, m in enumerate(proto.meshes) if m.is_leaf)


def leaf_primvar_edits(proto: Prototype, name: str, per_leaf: np.ndarray, *, type: str, element_size: int = 1) -> list[PrimvarEdit]:
    """One uniform primvar per leaf mesh of an editable prototype (empty for native-instance prototypes)."""
    edits = []
    for i, mesh in _leaf_meshes(proto):
        values = per_face(proto, i, per_leaf)
        if element_size > 1:
            values = values.reshape(-1)
        edits.append(PrimvarEdit(prim=mesh.path, name=name, values=values, type=type, interpolation="uniform", element_size=element_size))
    return edits


def vertex_primvar_edits(proto: Prototype, name: str, per_leaf: np.ndarray, *, type: str) -> list[PrimvarEdit]:
    """One vertex primvar per leaf mesh of an editable prototype: each vertex takes the value of its leaf.

    Vertices of degenerate faces (no leaf) get zeros.
    """
    edits = []
    for i, mesh in _leaf_meshes(proto):
        faces = per_face(proto, i, per_leaf)
        values = np.zeros((mesh.points.shape[0],) + faces.shape[1:])
        values[mesh.triangles.reshape(-1)] = np.repeat(faces[mesh.face_of_triangle], 3, axis=0)
        edits.append(PrimvarEdit(prim=mesh.path, name=name, values=values, type=type, interpolation="vertex"))
    return edits


#: Why per-leaf values cannot be stored on a native instance's meshes: the tail of :func:`native_instance_warning`.
NATIVE_INSTANCE_REASON = (
    "cannot be authored on its meshes (below an instanceable prim they are instance proxies, which USD keeps "
    "read-only); make the prototype editable (not instanceable) to store them."
)


def native_instance_warning(proto: Prototype, what: str) -> str:
    return f"prototype <{proto.path}> is a native instance: {what} {NATIVE_INSTANCE_REASON}"


def baked_sun_attribute(scene: Scene, index: int, method: str, sun_direction: np.ndarray) -> list[AttributeEdit]:
    """``foliage:<method>:sunDirection`` on prototype ``index``'s prim: the sun its per-leaf light was baked for.

    ``sun_direction`` is the world direction toward the sun; the attribute holds
    it in the prototype's own frame, as its first instance sees it (like the
    bake). The previewer compares it with the sun it draws under and warns when
    they differ: primvar-baked scattered light holds one sun only. Empty for
    native-instance prototypes, like the primvars.
    """
    from foliage_tools.pipeline.stage import first_instance_sun

    proto = scene.prototypes[index]
    if not proto.editable:
        return []
    d = tuple(float(v) for v in first_instance_sun(scene, index, sun_direction))
    return [AttributeEdit(prim=proto.path, api=None, values={f"foliage:{method}:sunDirection": (d, "Vector3f")})]
