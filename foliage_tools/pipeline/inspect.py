"""``foliage inspect``: what a stage holds, as the bakes will see it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from foliage_tools.pipeline.report import Report
from foliage_tools.scene.model import Scene
from foliage_tools.scene.read import LEAF_MESH_RULE, read_scene
from foliage_tools.pipeline.stats import InspectPrototypeStats, InspectStats


def _bounds_world(scene: Scene) -> list[list[float]] | None:
    corners = []
    for inst in scene.instances:
        b = scene.prototypes[inst.prototype].bounds()
        cube = np.array([[b[i, 0], b[j, 1], b[k, 2], 1.0] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
        corners.append((cube @ inst.transform.T)[:, :3])
    if not corners:
        return None
    c = np.concatenate(corners)
    return [c.min(axis=0).tolist(), c.max(axis=0).tolist()]


def _no_leaves(scene: Scene, path: Path) -> str | None:
    """Why the bakes would find no leaf in ``scene`` (they refuse it: ``density.require_leaves``), or None."""
    if any(p.leaves.count for p in scene.prototypes):
        return None
    n = sum(len(p.meshes) for p in scene.prototypes)
    read = f"none of the {n} mesh(es) read is a leaf mesh" if n else "no mesh was read"
    return (f"@{path}@ has no leaves: {read}, so every bake refuses it. A leaf is a connected piece of a leaf mesh, "
            f"and a leaf mesh is one with {LEAF_MESH_RULE}; invisible meshes, guide/proxy purposes and meshes without "
            "points or faces are left out. Mark the asset's leaf meshes one of these ways (`foliage validate` names "
            "what it finds).")


def inspect(path: Path) -> Report[InspectStats]:
    report: Report[InspectStats] = Report(command="inspect", inputs=[str(path)])
    scene, warnings = read_scene(path)
    report.warnings.extend(warnings)
    no_leaves = _no_leaves(scene, path)
    if no_leaves is not None:
        report.warnings.append(no_leaves)
    protos: list[InspectPrototypeStats] = []
    for i, p in enumerate(scene.prototypes):
        leaf_tris = sum(len(m.triangles) for m in p.meshes if m.is_leaf)
        wood_tris = sum(len(m.triangles) for m in p.meshes if not m.is_leaf)
        protos.append(
            {
                "path": p.path,
                "kind": p.kind,
                "instances": len(scene.instances_of(i)),
                "leaves": p.leaves.count,
                "leaf_area": float(p.leaves.areas.sum()),
                "leaf_triangles": leaf_tris,
                "wood_triangles": wood_tris,
                "leaf_meshes": [m.path for m in p.meshes if m.is_leaf],
                "wood_meshes": [m.path for m in p.meshes if not m.is_leaf],
                "bounds": p.bounds().tolist(),
            }
        )
    report.stats = {
        "up_axis": scene.up_axis,
        "meters_per_unit": scene.meters_per_unit,
        "prototypes": protos,
        "instances": len(scene.instances),
        "leaves_total": int(sum(scene.prototypes[i.prototype].leaves.count for i in scene.instances)),
        "bounds": _bounds_world(scene),
        "lights": [
            {"path": l.path, "kind": l.kind, "direction": l.direction.tolist(), "intensity": l.intensity, "color": list(l.color)}
            for l in scene.lights
        ],
    }
    return report.finish()
