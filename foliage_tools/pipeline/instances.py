"""Per-instance light: the mean irradiance of every placed tree, where it stands (issue #16).

Per-leaf primvars live on a prototype's meshes, so they hold one value per
leaf for all its instances (the mean over them). The light of an instance in
a stand differs from that of the same tree alone: its neighbours shade it and
scatter light onto it. What sees every instance — the exact direct light, the
final gather and the Monte Carlo reference trace all of them — is summarised
here per instance: the leaf-area-weighted mean E_direct and E_scattered over
the instance's leaves,

    E_n = sum_k A_k E_k / sum_k A_k   over the leaves k of instance n,

written where a renderer finds an instance:

* point-instancer instances: primvars ``foliage:<m>:instanceDirect`` and
  ``:instanceScattered`` (color3f, interpolation ``vertex``: one element per
  instance, in protoIndices order; masked instances hold 0) on the instancer;
* native instances and plain trees: the attributes of the same names on the
  instance's (or tree's) own prim, which is editable even when instanceable.

A renderer shades instance n with the prototype's per-leaf light times
E_n / (the prototype's mean), or with E_n alone.
"""

from __future__ import annotations

import re

import numpy as np

from foliage_tools.pipeline.world import World
from foliage_tools.scene.model import Scene
from foliage_tools.scene.write import AttributeEdit, PrimvarEdit

_INSTANCER = re.compile(r"^(?P<path>.+)\[(?P<index>\d+)\]$")


def instance_means(world: World, per_leaf: np.ndarray) -> np.ndarray:
    """(N, ...) leaf-area-weighted mean over each instance's leaves of a per-global-leaf array (0 if no area)."""
    per_leaf = np.asarray(per_leaf, dtype=np.float64)
    n = len(world.instance_prototype)
    out = np.zeros((n,) + per_leaf.shape[1:])
    for k in range(n):
        s = world.instance_slice(k)
        a = world.leaf_area[s]
        if a.sum() > 0:
            out[k] = np.tensordot(a, per_leaf[s], axes=(0, 0)) / a.sum()
    return out


def from_prototypes(world: World, per_prototype: dict[int, np.ndarray] | list[np.ndarray]) -> np.ndarray:
    """Per-global-leaf array of a method that has one value per prototype leaf (every instance the same)."""
    get = per_prototype.get if isinstance(per_prototype, dict) else (lambda p: per_prototype[p])
    n = int(world.offsets[-1])
    out = None
    for k, p in enumerate(world.instance_prototype):
        v = get(int(p))
        if v is None:
            continue
        v = np.asarray(v, dtype=np.float64)
        if out is None:
            out = np.zeros((n,) + v.shape[1:])
        out[world.instance_slice(k)] = v
    return np.zeros((n, 3)) if out is None else out


def instance_edits(scene: Scene, method: str, values: dict[str, np.ndarray]) -> tuple[list[PrimvarEdit], list[AttributeEdit]]:
    """Edits that store per-instance (N, 3) arrays ``values`` (name -> array, e.g. ``instanceDirect``) for ``method``.

    One primvar per name on each point instancer (its full length, masked instances 0), one attribute per name
    on each other instance's prim.
    """
    primvars: list[PrimvarEdit] = []
    attrs: list[AttributeEdit] = []
    per_instancer: dict[str, dict[str, np.ndarray]] = {}
    for n, inst in enumerate(scene.instances):
        m = _INSTANCER.match(inst.path)
        if m and m["path"] in scene.instancer_sizes:
            arrays = per_instancer.setdefault(m["path"], {name: np.zeros((scene.instancer_sizes[m["path"]], 3)) for name in values})
            for name, v in values.items():
                arrays[name][int(m["index"])] = v[n]
        else:
            attrs.append(AttributeEdit(prim=inst.path, api=None, values={
                f"foliage:{method}:{name}": (tuple(float(x) for x in v[n]), "Color3f") for name, v in values.items()}))
    for path, arrays in per_instancer.items():
        for name, arr in arrays.items():
            primvars.append(PrimvarEdit(prim=path, name=f"foliage:{method}:{name}", values=arr, type="color3f", interpolation="vertex"))
    return primvars, attrs


def bake_instance_edits(scene: Scene, method: str, world: World, e_direct: np.ndarray, e_scattered: np.ndarray,
                        forest=None, exact_direct=None) -> tuple[list[PrimvarEdit], list[AttributeEdit]]:
    """The per-instance means of a bake's per-global-leaf E_direct ((L,) or (L, 3)) and E_scattered ((L, 3)).

    ``forest`` (a ``pipeline.forest.ForestLight``): its factors multiply the scattered means of a method that lit
    each prototype alone, and are written too (``instanceScale``). Over a lone world (``world.bake_world``: a
    forest traced as its lone trees) every instance starts from its prototype's lone mean, and the direct mean is
    multiplied by the forest's direct factor as well (``instanceDirectScale``), unless ``exact_direct`` (a
    ``pipeline.direct.DirectBake``) traced each instance's direct mean through the placed forest: that mean is then
    written, and its ratio to the lone tree's as the scale.
    """
    d = np.asarray(e_direct, dtype=np.float64)
    if d.ndim == 1:
        d = np.repeat(d[:, None], 3, axis=1)
    direct, scattered = instance_means(world, d), instance_means(world, e_scattered)
    values = {}
    if world.lone:
        row = {int(p): r for r, p in enumerate(world.instance_prototype)}
        rows = [row[inst.prototype] for inst in scene.instances]
        direct, scattered = direct[rows], scattered[rows]
        if exact_direct is not None and exact_direct.instances is not None:
            traced = np.repeat(np.asarray(exact_direct.instances.e_direct)[:, None], 3, axis=1)
            values["instanceDirectScale"] = np.divide(traced, direct, out=np.ones_like(traced), where=direct > 0)
            direct = traced
        elif forest is not None:
            direct = direct * forest.direct_factors
            values["instanceDirectScale"] = np.asarray(forest.direct_factors, dtype=np.float64)
    values.update({"instanceDirect": direct, "instanceScattered": scattered})
    if forest is not None:
        values["instanceScattered"] = scattered * forest.factors
        values["instanceScale"] = np.asarray(forest.factors, dtype=np.float64)
    return instance_edits(scene, method, values)
