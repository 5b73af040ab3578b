"""shinya2013 eq. (31) for ``foliage spp``: each leaf's depths through the scene's other instances along world rays,
through each neighbour's prototype grid moved into place (grid depths) or the neighbours' triangles (ray depths)."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

import numpy as np

from foliage_tools.geometry.rays import RayScene
from foliage_tools.lighting import depth as depth_mod
from foliage_tools.lighting.spp import raydepth as rd
from foliage_tools.pipeline.density import DensityResult
from foliage_tools.scene.model import Scene

if TYPE_CHECKING:
    from foliage_tools.pipeline.spp import SppParams

#: Embree threads of the ray depths (results are identical for any number).
WORKERS = os.cpu_count() or 1


def is_similarity(m: np.ndarray) -> bool:
    """Rotation times a uniform scale plus a translation (optical depth is invariant under it), to
    :data:`~foliage_tools.lighting.depth.SIMILARITY_TOLERANCE` (PointInstancer ``quath`` orientations)."""
    lin = m[:3, :3]
    gram = lin.T @ lin
    s2 = float(np.trace(gram) / 3.0)
    return s2 > 0.0 and bool(np.allclose(gram, s2 * np.eye(3), rtol=0.0, atol=depth_mod.SIMILARITY_TOLERANCE * s2))


def world_points(points: np.ndarray, m: np.ndarray) -> np.ndarray:
    return points @ m[:3, :3].T + m[:3, 3]


class Neighbours:
    """Depths through the other instances of the scene along world rays (shinya2013 eq. (31))."""

    def __init__(self, scene: Scene, densities: dict[int, DensityResult], params: SppParams, warnings: list[str]) -> None:
        self.scene = scene
        self.densities = densities
        self.params = params
        self.usable = []
        skipped = []
        for n, inst in enumerate(scene.instances):
            if inst.prototype not in densities:
                continue
            if not is_similarity(inst.transform):
                skipped.append(f"<{inst.path}>")
                continue
            self.usable.append(n)
        if skipped:
            warnings.append(
                f"{len(skipped)} instance(s) ({', '.join(skipped[:3])}{', ...' if len(skipped) > 3 else ''}) are not placed by a "
                "rotation and a uniform scale: their leaves are left out of their neighbours' depths (shinya2013 eq. 31 needs "
                "optical depth to be invariant under the placement); give them uniform scales."
            )
        self._ray_scene = None
        if params.depth == "rays" and len(self.usable) > 1:
            tris, owner = [], []
            for n in self.usable:
                inst = scene.instances[n]
                t = scene.prototypes[inst.prototype].triangles(leaves=True)
                tris.append(t @ inst.transform[:3, :3].T + inst.transform[:3, 3])
                owner.append(np.full(len(t), n, dtype=np.int64))
            self._ray_scene = (RayScene(np.concatenate(tris)), np.concatenate(owner))

    def depths(self, n: int, world_centres: np.ndarray, sun_world, dirs_world) -> tuple[depth_mod.DepthSamples | None, int]:
        """Summed depths of instance n's leaf centres through every other usable instance, and how many there were."""
        others = [m for m in self.usable if m != n]
        if not others:
            return None, 0
        if self._ray_scene is not None:
            scene, owner = self._ray_scene
            # one world scene of every instance's leaves: the rays skip the triangles of their own instance
            return rd.ray_depth_samples(
                scene, world_centres, sun_direction=sun_world, directions=dirs_world,
                skip_ids=np.full(len(world_centres), n), id_of_triangle=owner, workers=WORKERS,
            ), len(others)
        total = None
        for proto_index in sorted({self.scene.instances[m].prototype for m in others}):
            mats = [np.linalg.inv(self.scene.instances[m].transform) for m in others if self.scene.instances[m].prototype == proto_index]
            dens = self.densities[proto_index]
            part = depth_mod.instance_depth_samples(
                dens.density, dens.grid, points=world_centres, sun_direction=sun_world, directions=dirs_world,
                prototype_from_world=np.asarray(mats),
            )
            total = part if total is None else total + part
        return total, len(others)
