"""``foliage smax`` end to end: primvars of DESIGN.md section 3, tau on the tree prim, sun choice, config files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from foliage_tools.lighting.optics import parse_leaf_optics
from foliage_tools.pipeline.smax import SmaxParams, run_smax
from tests.conftest import sha256
from tests.helpers.cli import foliage

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "tree_small.usda"


@pytest.fixture(scope="module")
def smax_out(tmp_path_factory):
    out = tmp_path_factory.mktemp("smax") / "t.usda"
    before = sha256(EXAMPLE)
    report = run_smax(EXAMPLE, out, SmaxParams(optics=parse_leaf_optics(None)))
    assert sha256(EXAMPLE) == before
    return out, report


def test_primvars_have_the_contracted_shapes(smax_out):
    from pxr import Usd, UsdGeom

    out, report = smax_out
    stage = Usd.Stage.Open(str(out))
    mesh = stage.GetPrimAtPath("/Tree/Leaves")
    faces = len(UsdGeom.Mesh(mesh).GetFaceVertexCountsAttr().Get())
    pv = UsdGeom.PrimvarsAPI(mesh)
    smax = pv.GetPrimvar("foliage:smax")
    assert smax.GetInterpolation() == "uniform" and smax.GetElementSize() == 8
    values = np.asarray(smax.Get()).reshape(faces, 8)
    att = np.asarray(pv.GetPrimvar("foliage:attenuation").Get()).reshape(faces, 8)
    tau = stage.GetPrimAtPath("/Tree").GetAttribute("foliage:tau").Get()
    assert stage.GetPrimAtPath("/Tree").HasAPI("FoliageEnvelopeAPI")
    # attenuation = exp(-tau s_max), the contract of DESIGN.md section 3
    np.testing.assert_allclose(att, np.exp(-tau * values), rtol=1e-5)
    assert np.all(values >= 0) and np.all(np.isfinite(values))
    direct = np.asarray(pv.GetPrimvar("foliage:smax:direct").Get())
    scattered = np.asarray(pv.GetPrimvar("foliage:smax:scattered").Get())
    assert direct.shape == scattered.shape == (faces, 3)
    # both faces summed, sun irradiance 1: E_direct of a leaf never exceeds 1
    assert np.all(direct >= 0) and np.all(direct <= 1 + 1e-6) and np.all(scattered >= 0)
    assert report.stats["tau"] == pytest.approx(tau, rel=1e-6)
    # provenance beside tau (FoliageEnvelopeAPI): which path, how long, which version
    tree = stage.GetPrimAtPath("/Tree")
    assert tree.GetAttribute("foliage:smax:path").Get() == report.stats["path"]
    assert tree.GetAttribute("foliage:smax:scatter").Get() == report.stats["prototypes"][0]["scatter"] == "march"
    assert tree.GetAttribute("foliage:smax:seconds").Get() > 0
    assert tree.GetAttribute("foliage:smax:version").Get()
    assert foliage("validate", out).returncode == 0


def test_sun_flag_overrides_the_stage_sun_with_the_same_angle_convention(tmp_path):
    optics = parse_leaf_optics(None)
    stage_sun = run_smax(EXAMPLE, tmp_path / "a.usda", SmaxParams(optics=optics))
    # the example's DistantLight sits at azimuth 45, elevation 60: the flag with those angles must agree exactly
    flag_same = run_smax(EXAMPLE, tmp_path / "b.usda", SmaxParams(optics=optics, sun=(45.0, 60.0)))
    run_smax(EXAMPLE, tmp_path / "c.usda", SmaxParams(optics=optics, sun=(225.0, 20.0)))
    assert stage_sun.stats["sun"]["source"] == "</Lights/Sun>" and flag_same.stats["sun"]["source"] == "--sun"
    a, b, c = (_direct(tmp_path / f"{n}.usda") for n in "abc")
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-7)
    # another sun lights other leaves: per-leaf values change substantially
    assert np.abs(a - c).mean() > 0.1 * a.mean()


def _direct(layer: Path) -> np.ndarray:
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(layer))
    return np.asarray(UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/Tree/Leaves")).GetPrimvar("foliage:smax:direct").Get())


def test_config_file_sets_options_and_flags_override(tmp_path):
    cfg = tmp_path / "bake.toml"
    cfg.write_text('leaf-optics = "bright"\n[smax]\nsun = "0,30"\n')
    r = foliage("smax", EXAMPLE, "-o", tmp_path / "c.usda", "--config", cfg, "--json")
    assert r.returncode == 0, r.stderr
    stats = json.loads(r.stdout)["stats"]
    assert stats["sun"]["elevation"] == pytest.approx(30.0) and stats["optics"]["reflectance"] == [0.45] * 3
    r = foliage("smax", EXAMPLE, "-o", tmp_path / "d.usda", "--config", cfg, "--sun", "10,70", "--json")
    assert json.loads(r.stdout)["stats"]["sun"]["elevation"] == pytest.approx(70.0)
    bad = tmp_path / "bad.toml"
    bad.write_text("colour = 3\n")
    r = foliage("smax", EXAMPLE, "-o", tmp_path / "e.usda", "--config", bad)
    assert r.returncode == 2 and "unknown key 'colour'" in r.stderr


def test_directions_flag_of_design_accepts_the_papers_8_and_refuses_others(tmp_path):
    # DESIGN.md section 3: `foliage smax SCENE -o OUT.usda [--directions 8]`
    r = foliage("smax", EXAMPLE, "-o", tmp_path / "d8.usda", "--directions", "8", "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["stats"]["leaves"] > 0
    r = foliage("smax", EXAMPLE, "-o", tmp_path / "d6.usda", "--directions", "6")
    assert r.returncode == 2 and "eq. 5.28" in r.stderr and "elementSize 8" in r.stderr
    assert not (tmp_path / "d6.usda").exists()


def test_config_keys_are_long_option_names_and_one_file_serves_every_command(tmp_path):
    # `path` is --path (its parameter is path_), `json` is --json; `resolution` belongs to lb/spp/density:
    # in the shared part of the file smax skips it, in smax's own table it is a mistake
    cfg = tmp_path / "pipeline.toml"
    cfg.write_text('resolution = 32\njson = true\n[smax]\npath = "reference"\n')
    r = foliage("smax", EXAMPLE, "-o", tmp_path / "a.usda", "--config", cfg)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["stats"]["path"] == "reference"
    bad = tmp_path / "bad.toml"
    bad.write_text("[smax]\nresolution = 32\n")
    r = foliage("smax", EXAMPLE, "-o", tmp_path / "b.usda", "--config", bad)
    assert r.returncode == 2 and "unknown key 'resolution'" in r.stderr and "leaf-optics" in r.stderr
    # a value one command takes and another refuses (lb's first order `field` is not spp's): the error names the
    # file, the key and where to put it, before any work
    shared = tmp_path / "shared.toml"
    shared.write_text('first-order = "field"\n')
    r = foliage("spp", EXAMPLE, "-o", tmp_path / "c.usda", "--config", shared)
    assert r.returncode == 2, r.stderr
    assert "shared.toml" in r.stderr and "top-level key 'first-order'" in r.stderr and "[spp]" in r.stderr
    assert not (tmp_path / "c.usda").exists()
    # a misspelt table is not skipped silently
    typo = tmp_path / "typo.toml"
    typo.write_text("[smaxx]\npath = 'reference'\n")
    r = foliage("smax", EXAMPLE, "-o", tmp_path / "d.usda", "--config", typo)
    assert r.returncode == 2 and "typo.toml" in r.stderr and "[smaxx] is not a foliage command" in r.stderr, r.stderr
    # the sun as TOML spells a pair, and a bad sun named by file and key
    sun = tmp_path / "sun.toml"
    sun.write_text("json = true\nsun = [30, 50]\n")
    r = foliage("smax", EXAMPLE, "-o", tmp_path / "e.usda", "--config", sun)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["stats"]["sun"]["elevation"] == 50.0
    assert json.loads(r.stdout)["stats"]["sun"]["source"] == f"--config {sun}"  # not "--sun": the file set it
    # any comma-separated option spelt as a TOML array, checked by the option's own parsing
    sun.write_text("json = true\nleaf-optics = [0.45, 0.40]\n")
    r = foliage("smax", EXAMPLE, "-o", tmp_path / "e2.usda", "--config", sun)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["stats"]["optics"]["transmittance"] == [0.40, 0.40, 0.40]
    sun.write_text('sun = "45;60"\n')
    r = foliage("smax", EXAMPLE, "-o", tmp_path / "f.usda", "--config", sun)
    assert r.returncode == 2 and "sun.toml" in r.stderr and "key 'sun'" in r.stderr, r.stderr
    # an editor's byte-order mark is read past; a fraction or a boolean for a whole number is refused, not truncated
    bom = tmp_path / "bom.toml"
    bom.write_bytes("\ufeffjson = true\n".encode("utf-8"))
    r = foliage("smax", EXAMPLE, "-o", tmp_path / "g.usda", "--config", bom)
    assert r.returncode == 0 and json.loads(r.stdout)["stats"]["prototypes"], r.stderr
    for text in ("directions = 8.5\n", "directions = true\n"):
        frac = tmp_path / "frac.toml"
        frac.write_text(text)
        r = foliage("smax", EXAMPLE, "-o", tmp_path / "h.usda", "--config", frac)
        assert r.returncode == 2 and "frac.toml" in r.stderr and "not a whole number" in r.stderr, r.stderr


def test_bad_leaf_optics_is_a_usage_error(tmp_path):
    r = foliage("smax", EXAMPLE, "-o", tmp_path / "o.usda", "--leaf-optics", "0.7,0.7")
    assert r.returncode == 2 and "≤ 1" in r.stderr


@pytest.mark.parametrize(
    "asset", ["webots_oak/oak.usda", "webots_bigsassafras/big_sassafras.usda", "sapling_blendertree/blender_tree.usda"]
)
def test_runs_on_third_party_trees(asset, tmp_path):
    from tests.conftest import ASSETS

    path = ASSETS / asset
    if not path.exists():
        pytest.skip("third-party assets not present")
    report = run_smax(path, tmp_path / "o.usda", SmaxParams(optics=parse_leaf_optics(None)))
    p = report.stats["prototypes"][0]
    assert p["tau"] > 0 and np.isfinite(p["tau"]) and p["smax_mean"] > 0
    assert 0 < p["e_direct_mean"][1] <= 1


@pytest.mark.slow
def test_generated_40k_leaf_tree_uses_the_fast_path(tmp_path):
    import sys

    sys.path.insert(0, str(EXAMPLE.parent))
    from make_tree import build_tree, write_tree

    geo = build_tree(leaves=40000, leaf_size=0.05, crown="ellipsoid", height=6.0, crown_radius=2.0, seed=3)
    write_tree(tmp_path / "t40k.usdc", geo)
    report = run_smax(tmp_path / "t40k.usdc", tmp_path / "o.usda", SmaxParams(optics=parse_leaf_optics(None)))
    assert report.stats["leaves"] == 40000 and report.stats["path"] == "fast"


def test_scattered_light_against_the_reference_and_the_papers_own(smax_out, tmp_path):
    """The default (--scatter march) against the Monte Carlo reference on the example, crown means: within 12 %,
    the budget of the ball test in tests/unit/test_smax_scatter.py (the 8 octant bins over a crown, which the
    higher orders' p shares); measured 0.95 here over the channels (0.98 on the oak, 0.99 on the sapling;
    --scatter leaves 0.97 / 0.89 / 1.03). --scatter paper is the thesis' eq. (5.24) exactly, recomputed
    from the written s_max and tau, and reads 0.84 of the reference here."""
    from pxr import Usd, UsdGeom

    from foliage_tools.lighting.envelope import boulanger
    from foliage_tools.pipeline.reference import ReferenceParams, bake_reference
    from foliage_tools.pipeline.report import Silent
    from foliage_tools.pipeline.stage import begin_bake

    out, report = smax_out
    assert report.stats["prototypes"][0]["scatter"] == "march"
    optics = parse_leaf_optics(None)
    paper = run_smax(EXAMPLE, tmp_path / "p.usda", SmaxParams(optics=optics, scatter="paper", sun=(45.0, 60.0)))
    assert paper.stats["prototypes"][0]["scatter"] == "paper"
    _, scene, sun = begin_bake("bench", EXAMPLE, None, (45.0, 60.0), Silent())
    ref = bake_reference(scene, sun, ReferenceParams(optics=optics, paths=2_000_000, seed=0), Silent()).result
    leaves = scene.prototypes[0].leaves

    def per_leaf(path, name):
        stage = Usd.Stage.Open(str(path))  # kept alive while its prims are read
        values = np.asarray(UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/Tree/Leaves")).GetPrimvar(name).Get(),
                            dtype=np.float64)
        mesh_index = next(i for i, m in enumerate(scene.prototypes[0].meshes) if m.path == "/Tree/Leaves")
        ids = leaves.face_leaf_ids[mesh_index]
        if values.ndim == 1 and values.size != len(ids):  # elementSize 8
            values = values.reshape(len(ids), -1)
        per = np.zeros((leaves.count,) + values.shape[1:])
        per[ids[ids >= 0]] = values[ids >= 0]
        return per

    ours = per_leaf(out, "foliage:smax:scattered")[:, 1]
    assert abs(ours.mean() / ref.e_scattered[:, 1].mean() - 1.0) <= 0.12
    written = per_leaf(tmp_path / "p.usda", "foliage:smax:scattered")
    paper_stage = Usd.Stage.Open(str(tmp_path / "p.usda"))
    tau = paper_stage.GetPrimAtPath("/Tree").GetAttribute("foliage:tau").Get()
    assert paper_stage.GetPrimAtPath("/Tree").GetAttribute("foliage:smax:scatter").Get() == "paper"
    again = boulanger.solve(leaves.normals, per_leaf(tmp_path / "p.usda", "foliage:smax").reshape(-1, 8), tau,
                            params=boulanger.BoulangerParams(sun_direction=tuple(sun.direction),
                                                             reflectance=tuple(optics.reflectance),
                                                             transmittance=tuple(optics.transmittance)))
    np.testing.assert_allclose(written, again.e_scattered, rtol=2e-4, atol=1e-7)
    assert written[:, 1].mean() / ref.e_scattered[:, 1].mean() < 0.9


def test_density_plan_and_preview_read_the_shared_config_too(tmp_path):
    # they had no --config, so a pipeline's file could not set their resolution, sun or size (a new user's trial)
    cfg = tmp_path / "pipeline.toml"
    cfg.write_text('resolution = 16\nsun = "30,40"\nsize = "96x64"\nmax-sweeps = 5\njson = true\n[preview]\nmethod = "direct"\n')
    r = foliage("density", EXAMPLE, "-o", tmp_path / "d.usda", "--config", cfg)
    assert r.returncode == 0, r.stderr
    assert max(json.loads(r.stdout)["stats"]["prototypes"][0]["shape"]) == 16 + 2  # the file's 16, one margin voxel a side
    r = foliage("plan", EXAMPLE, "--config", cfg)
    assert r.returncode == 0 and json.loads(r.stdout)["stats"]["resolution"] == 16, r.stderr
    r = foliage("preview", EXAMPLE, "-o", tmp_path / "p.png", "--config", cfg)
    assert r.returncode == 0, r.stderr
    st = json.loads(r.stdout)["stats"]
    assert st["size"] == [96, 64] and st["sun"]["elevation"] == 40.0 and st["sun"]["source"] == f"--config {cfg}"
