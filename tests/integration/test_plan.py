"""``foliage plan``: grids and memory that match what the bakes build, and nothing written."""

import json

import pytest
from pathlib import Path

from tests.helpers.cli import foliage

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "tree_small.usda"


def test_plan_grid_matches_the_density_bake_and_writes_nothing(tmp_path):
    before = sorted(p.name for p in EXAMPLE.parent.iterdir())
    r = foliage("plan", EXAMPLE, "--resolution", "16", "--json")
    assert r.returncode == 0, r.stderr
    plan = json.loads(r.stdout)["stats"]["prototypes"][0]
    d = foliage("density", EXAMPLE, "-o", tmp_path / "d.usda", "--resolution", "16", "--json")
    assert d.returncode == 0, d.stderr
    dens = json.loads(d.stdout)["stats"]["prototypes"][0]
    assert plan["grid"] == dens["shape"]  # the grid lb/spp would build is the density grid
    assert sorted(p.name for p in EXAMPLE.parent.iterdir()) == before
    assert json.loads(r.stdout)["outputs"] == []


def test_plan_lb_memory_follows_the_right_hand_sides():
    sun = json.loads(foliage("plan", EXAMPLE, "--resolution", "32", "--json").stdout)["stats"]
    all_ = json.loads(foliage("plan", EXAMPLE, "--resolution", "32", "--bases", "all", "--json").stdout)["stats"]
    p_sun, p_all = sun["prototypes"][0], all_["prototypes"][0]
    assert (p_sun["lb_rhs"], p_all["lb_rhs"]) == (3, 54)  # RGB x (sun | 18 Kronecker bases)
    nodes = p_sun["grid"][0] * p_sun["grid"][1] * p_sun["grid"][2]
    assert p_sun["lb_memory_bytes"] >= 2 * 72 * 3 * nodes  # two fields of 18 float32 per rhs at least
    # 18x the right-hand sides; the sun bake holds its beam arrays and the single-scattering correction on top of
    # the 2.3 fields of plain iteration (0.9 field more), the relightable one 2.1 fields (lb.RELIGHTABLE_ITERATION_FIELDS)
    assert p_all["lb_memory_bytes"] == pytest.approx(18 * p_sun["lb_memory_bytes"] * 2.1 / 3.2, rel=1e-6)  # whole bytes
    # 18x the sweeps (a faster kernel per rhs); the per-node work (density, beams: the same) and the sun bake's
    # exact first order (only there) do not scale with the right-hand sides. --gather auto runs in the sun bake
    # only (it does not gather --bases all), so the lattices compare without it
    from foliage_tools.pipeline.plan import GATHER_RAYS_PER_S

    gather_s = sun["gather_rays"] / GATHER_RAYS_PER_S
    assert gather_s > 0 and all_["gather_rays"] == sun["gather_rays"]  # the same leaves; spp gathers either way
    assert all_["seconds_estimate"]["lb"] > sun["seconds_estimate"]["lb"] - gather_s
    # --storage fp16: the two fields of plain iteration in 2 bytes per value, the other 0.1 field float32, and the
    # bases' beam source (lb.BEAM_SOURCE_FIELDS: 0.1 field float32)
    half = json.loads(foliage("plan", EXAMPLE, "--resolution", "32", "--bases", "all", "--storage", "fp16", "--json").stdout)["stats"]
    assert half["storage"] == "fp16"
    # more sweeps (its ordered sweeps stop one measurement after the rounding level), each cheaper: same seconds
    assert half["prototypes"][0]["lb_sweeps_estimate"] == 13 and p_all["lb_sweeps_estimate"] == 7
    assert half["seconds_estimate"]["lb"] == pytest.approx(all_["seconds_estimate"]["lb"], rel=1e-9)
    assert half["prototypes"][0]["lb_memory_bytes"] == pytest.approx(p_all["lb_memory_bytes"] * 1.2 / 2.1, rel=1e-6)  # whole bytes


def test_plan_counts_every_instance_of_a_forest():
    from foliage_tools.scene.read import read_scene

    forest = EXAMPLE.with_name("forest_small.usda")
    st = json.loads(foliage("plan", forest, "--json").stdout)["stats"]
    scene, _ = read_scene(forest)
    tris = sum(len(m.triangles) for m in scene.prototypes[0].meshes)
    assert st["instances"] == 16 and st["world_triangles"] == 16 * tris  # the ray scene holds every instance's copy
    assert st["world_memory_bytes"] > 16 * tris * 500
    # the forest lattice: 24 cells across the crown over the whole forest's extent, a time per stage
    assert st["forest"]["nodes"] > 16**3 and st["seconds_estimate"]["forest"] > 0
    alone = json.loads(foliage("plan", EXAMPLE, "--json").stdout)["stats"]
    assert alone["forest"] is None and "forest" not in alone["seconds_estimate"]


def test_plan_of_a_forest_too_large_to_copy_traces_its_lone_trees(tmp_path):
    # 55 x 55 instances of the example tree place ~16M triangles, above world.WORLD_MAX_TRIANGLES: the shadow rays
    # and the gather trace the prototype alone (the forest lattice brings the stand), the reference its placements
    import sys

    from foliage_tools.pipeline.plan import ray_scene_bytes
    from foliage_tools.pipeline.world import WORLD_MAX_TRIANGLES
    from foliage_tools.scene.read import read_scene

    sys.path.insert(0, str(EXAMPLE.parent))
    from make_forest import plan_stand, tree_radius_of, write_forest

    path = write_forest(tmp_path / "stand.usdc", EXAMPLE, plan_stand(side=55, tree_radius=tree_radius_of(EXAMPLE), seed=1))
    st = json.loads(foliage("plan", path, "--json").stdout)["stats"]
    tris = sum(len(m.triangles) for m in read_scene(EXAMPLE)[0].prototypes[0].meshes)
    assert st["instances"] == 55 * 55 and st["world_triangles"] == 55 * 55 * tris > WORLD_MAX_TRIANGLES
    assert st["traced"] == "lone trees" and st["traced_triangles"] == tris
    # the prototype's leaves at --direct-samples auto's most, and 4096 rays for each instance's mean
    assert st["direct_rays"] == 1500 * 1024 + 55 * 55 * 4096
    # the reference traces the placed prototype too (geometry.instanced): its memory is the prototype's ray scene
    # plus per-instance tallies, far below the 3025 copies' (~12 GB)
    assert st["world_memory_bytes"] < st["reference_memory_bytes"] < st["world_memory_bytes"] + 0.1e9
    assert ray_scene_bytes(st["world_triangles"]) > 10 * st["reference_memory_bytes"]
    assert st["forest"]["nodes"] > 16**3


def test_the_reference_refuses_a_forest_whose_ray_scene_does_not_fit(monkeypatch):
    from foliage_tools.errors import UsageError
    from foliage_tools.geometry.sun import choose_sun
    from foliage_tools.lighting.optics import parse_leaf_optics
    from foliage_tools.pipeline import plan
    from foliage_tools.pipeline.reference import ReferenceParams, bake_reference
    from foliage_tools.pipeline.report import Silent
    from foliage_tools.scene.read import read_scene

    scene, _ = read_scene(EXAMPLE.with_name("forest_small.usda"))
    monkeypatch.setattr(plan, "available_memory", lambda: 1e8)  # less than 16 instances' ray scene (~0.45 GB)
    with pytest.raises(UsageError, match=r"traces every instance: 16 instances .* more than the 0\.1 GB free"):
        bake_reference(scene, choose_sun(scene.lights, scene.up_axis, (0.0, 45.0), []),
                       ReferenceParams(optics=parse_leaf_optics(None), paths=1000), Silent())


@pytest.mark.parametrize("storage", ["fp32", "fp16"])
def test_plan_peak_memory_predicts_the_relightable_bakes_measured_peak(tmp_path, storage):
    """The peak `plan` gives is what decides, before a bake, whether it fits: against the bake's own peak resident
    memory (ru_maxrss of `foliage lb` run alone in a fresh process), at 64^3 with 18 bases x RGB, where the LB
    fields dominate. It must not fall short by more than 5 % (a bake that fits on paper but not in memory is the
    failure that matters), nor overstate by more than 25 % (the pre-solve check would refuse bakes that fit)."""
    import subprocess
    import sys

    args = [EXAMPLE, "--resolution", "64", "--bases", "all", "--storage", storage]
    plan = json.loads(foliage("plan", *args, "--json").stdout)["stats"]
    measure = ("import resource, subprocess, sys; subprocess.run(sys.argv[1:], check=True, capture_output=True); "
               "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)")
    cmd = [sys.executable, "-m", "foliage_tools", "lb", *map(str, args), "-o", str(tmp_path / "b.usda"), "--gather", "0"]
    out = subprocess.run([sys.executable, "-c", measure, *cmd], capture_output=True, text=True, timeout=300, check=True)
    measured = int(out.stdout.split()[-1]) * 1024  # ru_maxrss: KiB on Linux
    assert 0.8 * plan["peak_memory_bytes"] <= measured <= 1.05 * plan["peak_memory_bytes"], (measured, plan["peak_memory_bytes"])
