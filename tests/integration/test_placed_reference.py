"""The Monte Carlo reference traced through placed prototypes (nothing copied) against the copied world.

A forest above world.WORLD_MAX_TRIANGLES is traced through its placements (geometry.instanced): one ray scene
per prototype, every prototype leaf pooled over its instances, each instance's means tallied apart. The
independent answer is the same reference over every instance's copied triangles (the scheme validated against
Cycles), run here on the bundled forest with another seed: the two estimate the same expectations, so they
differ by their noise alone.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from foliage_tools.bench.metrics import rel_rms
from foliage_tools.geometry.sun import choose_sun
from foliage_tools.lighting import reference
from foliage_tools.lighting.optics import parse_leaf_optics
from foliage_tools.pipeline import reference as stage
from foliage_tools.pipeline.instances import instance_means
from foliage_tools.pipeline.reference import ReferenceParams, bake_reference, run_reference
from foliage_tools.pipeline.report import Silent
from foliage_tools.scene.read import open_stage, read_scene

FOREST = Path(__file__).resolve().parents[2] / "examples" / "forest_small.usda"
OPTICS = parse_leaf_optics(None)
PATHS = 400_000


def _sun(scene):
    return choose_sun(scene.lights, scene.up_axis, (30.0, 50.0), [])


def test_placed_instances_and_pooled_leaves_match_the_copied_world(tmp_path, monkeypatch):
    scene, _ = read_scene(FOREST)
    sun = _sun(scene)
    flat = bake_reference(scene, sun, ReferenceParams(optics=OPTICS, paths=PATHS, seed=1), Silent())
    assert flat.world is not None and flat.result.instance_direct is None
    flat_inst = instance_means(flat.world, flat.result.e_direct + flat.result.e_scattered)

    # the same command, with the forest taken as one too large to copy
    monkeypatch.setattr(stage, "traced_alone", lambda scene, triangles=None: True)
    out = tmp_path / "f.ref.usda"
    report = run_reference(FOREST, out, ReferenceParams(optics=OPTICS, sun=(30.0, 50.0), paths=PATHS, seed=2))
    placed = bake_reference(scene, sun, ReferenceParams(optics=OPTICS, paths=PATHS, seed=2), Silent())
    assert placed.world is None and placed.pooled is not None
    res = placed.result
    noise = float(res.noise_rel_instance)
    assert 0 < noise < 0.03 and report.stats["noise_rel_instance"] == noise
    inst = res.instance_direct + res.instance_scattered
    # each instance's mean total: the two runs differ by both runs' noise; the copied world's per-instance noise
    # is taken equal to the placed one's (same paths; the placed source is the noisier, 0.36 against 0.31 per
    # leaf), so 3 x sqrt(2) x noise is three standard deviations of the difference
    assert rel_rms(inst, flat_inst) < 3 * np.sqrt(2) * noise
    # no bias: the forest's mean over all instances, whose noise is ~noise / sqrt(16)
    assert abs(inst[:, 1].mean() / flat_inst[:, 1].mean() - 1) < 3 * np.sqrt(2) * noise / 4

    # the pooled leaves: each prototype leaf's area-weighted mean over its instances, as the copied world gives it
    counts = [p.leaves.count for p in scene.prototypes]
    for name in ("e_scattered", "e_direct"):
        mine = placed.prototype_values(getattr(res, name), counts)
        theirs = flat.prototype_values(getattr(flat.result, name), counts)
        for p in range(len(counts)):
            if counts[p]:
                # per leaf the pooled value has the noise of one run over its prototype's leaves; both runs' noise
                # per leaf is ~noise_rel (E_scattered) or noise_rel_direct, estimated per run
                bound = 1.5 * np.hypot(getattr(res, "noise_rel" if name == "e_scattered" else "noise_rel_direct"),
                                       getattr(flat.result, "noise_rel" if name == "e_scattered" else "noise_rel_direct"))
                assert rel_rms(mine[p], theirs[p]) < bound, (name, p)

    # energy: every launched photon's power is absorbed or escapes, summed over channels exactly (per path)
    assert np.isclose((res.absorbed.sum() + res.absorbed_wood.sum() + res.escaped.sum()), res.incident.sum(), rtol=1e-9)

    # what the layer holds: the instancer's per-instance means, in protoIndices order
    from pxr import UsdGeom

    layer = open_stage(out)
    grove = UsdGeom.PrimvarsAPI(layer.GetPrimAtPath("/World/Grove"))
    d = np.asarray(grove.GetPrimvar("foliage:ref:instanceDirect").Get(), dtype=np.float64)
    rows = [k for k, i in enumerate(scene.instances) if i.path.startswith("/World/Grove[")]
    np.testing.assert_allclose(d, res.instance_direct[rows], rtol=1e-5)  # float32 storage


def test_placements_refuse_what_they_cannot_trace():
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], dtype=float)
    pl = reference.Placements((tri,), (np.array([0]),), np.eye(4)[None], np.array([0]), np.array([0]))
    import pytest

    with pytest.raises(ValueError, match="placements replace triangles"):
        reference.ReferenceInputs(triangles=tri, leaf_of_triangle=np.array([0]), leaf_area=np.ones(1),
                                  optics=OPTICS, sun_direction=(0, 0, 1), placements=pl)
    with pytest.raises(ValueError, match="tally into 1 leaves but leaf_area has 0"):
        reference.ReferenceInputs(triangles=np.zeros((0, 3, 3)), leaf_of_triangle=np.zeros(0, np.int64),
                                  leaf_area=np.ones(0), optics=OPTICS, sun_direction=(0, 0, 1), placements=pl)


def test_placed_leaf_areas_are_the_copied_worlds(rng):
    # cof(A) a against the copied triangles' own areas, with sheared and scaled instances
    from foliage_tools.pipeline.world import assemble, prototype_geometry

    scene, _ = read_scene(FOREST)
    tris, leaves = prototype_geometry(scene)
    m = np.array([i.transform for i in scene.instances])
    m[:, :3, :3] = m[:, :3, :3] @ (np.eye(3) + 0.3 * rng.uniform(-1, 1, (len(m), 3, 3)))
    proto = np.array([i.prototype for i in scene.instances])
    world = assemble(replace(scene, instances=tuple(replace(i, transform=t) for i, t in zip(scene.instances, m))))
    pl = reference.Placements(tris, leaves, m, proto, world.offsets[:-1])
    leaf_area, inst_area = pl.areas
    np.testing.assert_allclose(leaf_area, world.leaf_area, rtol=1e-12)
    np.testing.assert_allclose(inst_area, np.add.reduceat(world.leaf_area, world.offsets[:-1]), rtol=1e-12)
