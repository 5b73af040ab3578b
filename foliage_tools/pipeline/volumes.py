"""Where a prototype's ``FoliageLighting`` volume goes, and how it is placed over the instances it lights.

An editable prototype (plain geometry, a point instancer's own prototype)
holds its volume as a child, ``<tree>/FoliageLighting`` (DESIGN.md section 3):
the volume is in prototype space and goes wherever the tree goes, once per
point-instanced copy too.

A native-instance prototype cannot hold it: the instance's descendants are
instance proxies, which take no edits (issues #16, #17). Its volume is
authored once, in prototype space, inside a USD ``class``

    <defaultPrim>/FoliageBakes/Prototypes/<name>/FoliageLighting

which is not drawn (a class prim is abstract: USD's default traversal and
Hydra skip it; Blender 5.0.1 does not import it, measured in
tests/integration/test_blender_roundtrip.py), and each instance of the prototype -- native instances, and the
point-instanced copies of an instanceable prototype -- gets a prim

    <defaultPrim>/FoliageBakes/Instances/<instance>      (references the class)
    <defaultPrim>/FoliageBakes/Instances/<instance>/FoliageLighting

with the instance's transform relative to the default prim, so the volume
lands over that tree. Why this shape:

* one set of fields and one ``.vdb`` file per prototype, shared through the
  internal reference (nothing is copied per instance; a later stage that
  rewrites the class's fields reaches every placement through composition);
* everything under the default prim, so a DCC that imports the default prim
  (or references the bake into a shot) gets the volumes, and the world-space
  ``FoliageForest`` volume beside them (``pipeline.forest``);
* plain references, not ``instanceable`` placements: every DCC composes a
  referenced prim, while instanced volumes are not known to import
  everywhere; a placement costs a handful of opinions, not a copy of the grids.
"""

from __future__ import annotations

import re

import numpy as np

from foliage_tools.scene.model import Prototype, Scene
from foliage_tools.scene.vdb import Grid
from foliage_tools.scene.write import VolumeEdit, VolumePlacement

VOLUME_NAME = "FoliageLighting"


def _prim_name(text: str) -> str:
    name = re.sub(r"[^A-Za-z0-9_]", "_", text).strip("_") or "root"
    return name if not name[0].isdigit() else f"_{name}"


def bakes_root(scene: Scene) -> str:
    """``<defaultPrim>/FoliageBakes`` (``/FoliageBakes`` on a stage without a default prim)."""
    return f"{scene.default_prim or ''}/FoliageBakes"


def class_path(scene: Scene, proto: Prototype) -> str:
    """The ``class`` prim holding a native-instance prototype's volume."""
    return f"{bakes_root(scene)}/Prototypes/{_prim_name(proto.name)}"


def volume_path(scene: Scene, proto: Prototype) -> str:
    """The prim path of a prototype's ``FoliageLighting`` volume, as the stages author and read it (module docstring)."""
    if proto.editable:
        return f"{proto.path}/{VOLUME_NAME}"
    return f"{class_path(scene, proto)}/{VOLUME_NAME}"


def placements(scene: Scene, index: int) -> tuple[VolumePlacement, ...]:
    """One placement per instance of native-instance prototype ``index`` (none for an editable prototype).

    Its transform is default-prim-from-prototype: the instance's
    world-from-prototype matrix with the default prim's own transform taken
    out, since the placing prim's parents (``FoliageBakes``, ``Instances``) are
    untransformed ``Scope`` s.
    """
    if scene.prototypes[index].editable:
        return ()
    root_from_world = np.linalg.inv(np.asarray(scene.default_prim_transform, dtype=np.float64))
    names = _placement_paths(scene)
    return tuple(VolumePlacement(path=names[n], transform=root_from_world @ np.asarray(inst.transform, dtype=np.float64),
                                 instance=inst.path)
                 for n, inst in enumerate(scene.instances) if inst.prototype == index)


def _placement_paths(scene: Scene) -> dict[int, str]:
    """Instance number -> its placing prim, for every instance of a native-instance prototype.

    Named after the instance's path below the default prim (``Trees/Tree_00``
    -> ``Trees_Tree_00``, ``Grove[3]`` -> ``Grove_3``); a name two instances
    would share gets ``_2``, ``_3``, ... in instance order, so the names are the
    same on every run over the same scene.
    """
    root = scene.default_prim or ""
    taken: set[str] = set()
    out = {}
    for n, inst in enumerate(scene.instances):
        if scene.prototypes[inst.prototype].editable:
            continue
        rel = inst.path[len(root) + 1:] if root and inst.path.startswith(root + "/") else inst.path.lstrip("/")
        base = f"{bakes_root(scene)}/Instances/{_prim_name(rel)}"
        path, k = base, 1
        while path in taken:
            k += 1
            path = f"{base}_{k}"
        taken.add(path)
        out[n] = path
    return out


def prototype_volume(scene: Scene, index: int, *, vdb_file, grids: tuple[Grid, ...], attributes: dict,
                     purpose: str) -> VolumeEdit:
    """The ``VolumeEdit`` of prototype ``index``'s grids: in the prototype, or in its class with its placements."""
    proto = scene.prototypes[index]
    return VolumeEdit(path=volume_path(scene, proto), vdb_file=vdb_file, grids=tuple(grids), attributes=attributes,
                      purpose=purpose, class_prim=None if proto.editable else class_path(scene, proto),
                      placements=placements(scene, index))
