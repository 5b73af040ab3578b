"""``lb --gather`` and ``spp --gather``: the final gather written by the bakes, against the Monte Carlo reference."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from foliage_tools.lighting.optics import parse_leaf_optics
from foliage_tools.pipeline.lb import LBBakeParams, run_lb
from foliage_tools.pipeline.reference import ReferenceParams, run_reference
from foliage_tools.pipeline.spp import SppParams, run_spp
from foliage_tools.scene.read import open_stage
from tests.helpers.cli import foliage

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "tree_small.usda"
RAYS = 256


def _primvar(layer: Path, name: str, mesh="/Tree/Leaves") -> np.ndarray:
    from pxr import UsdGeom

    stage = open_stage(layer)
    return np.asarray(UsdGeom.PrimvarsAPI(stage.GetPrimAtPath(mesh)).GetPrimvar(name).Get())


@pytest.fixture(scope="module")
def bakes(tmp_path_factory):
    d = tmp_path_factory.mktemp("gather")
    optics = parse_leaf_optics(None)
    reports = {
        "ref": run_reference(EXAMPLE, d / "ref.usda", ReferenceParams(optics=optics, paths=2_000_000, seed=1)),
        # the default: --gather auto (1024 rays per leaf for 1500 leaves)
        "lb": run_lb(EXAMPLE, d / "lb.usda", LBBakeParams(optics=optics, resolution=16)),
        "lb-plain": run_lb(EXAMPLE, d / "lbp.usda", LBBakeParams(optics=optics, resolution=16, gather=0)),
        # SPP at 32: the gather takes its later bounces from SPP's exact slab, which on a 16^3 grid of this crown
        # reads them so high that the gathered crown mean was +5.1 % (measured; SPPG's G hid it at 16)
        "spp": run_spp(EXAMPLE, d / "spp.usda", SppParams(optics=optics, resolution=32, depth="grid", gather=RAYS)),
    }
    return d, reports


def _rel_rms(a: np.ndarray, ref: np.ndarray) -> float:
    g = a[:, 1]  # green: the brightest channel, the least noisy
    return float(np.sqrt(np.mean((g - ref[:, 1]) ** 2)) / np.mean(ref[:, 1]))


@pytest.mark.parametrize("layer, name", [("lb.usda", "foliage:lb:scattered"), ("spp.usda", "foliage:sppg:scattered")])
def test_gathered_scattered_light_matches_the_reference_leaf_by_leaf(bakes, layer, name):
    d, reports = bakes
    ref = _primvar(d / "ref.usda", "foliage:ref:scattered")
    got = _primvar(d / layer, name)
    method = layer.split(".")[0]
    noise_gather = reports[method].stats["gather"]["noise_rel"]
    noise_ref = reports["ref"].stats["noise_rel"]
    # The first bounce (~90 % of E_scattered here, `first_bounce_share`) is exact up to the gather's sampling
    # noise; the later bounces (~10 %) carry the volume method's error, at most ~35 % per leaf on tree_small
    # (the bench) -> 0.035. Sampling noise of both sides adds in quadrature; 1.25 covers the error of the
    # two-halves noise estimates (each from 1500 leaves: a few per cent) with margin.
    bound = 1.25 * np.hypot(noise_gather, noise_ref) + 0.035
    err = _rel_rms(got, ref)
    assert err <= bound, (name, err, bound)
    # and the mean over the crown: sampling noise averages out over 1500 leaves, the later bounces' error does not
    assert got[:, 1].mean() == pytest.approx(ref[:, 1].mean(), rel=0.04)
    assert 0.7 < reports[method].stats["gather"]["first_bounce_share"] < 1


def test_lb_gather_replaces_the_lattice_scattered_light_and_its_vertex_primvar(bakes):
    d, reports = bakes
    ref = _primvar(d / "ref.usda", "foliage:ref:scattered")
    plain = _primvar(d / "lbp.usda", "foliage:lb:scattered")
    gathered = _primvar(d / "lb.usda", "foliage:lb:scattered")
    # without the gather the 16^3 lattice is far from the reference leaf by leaf: the gather is what is written
    assert _rel_rms(plain, ref) > 1.5 * _rel_rms(gathered, ref)
    # lbIndirect holds each vertex's leaf value (per leaf, no longer interpolated in the lattice)
    from pxr import UsdGeom

    stage = open_stage(d / "lb.usda")
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Tree/Leaves"))
    vertex = np.asarray(UsdGeom.PrimvarsAPI(mesh).GetPrimvar("foliage:lbIndirect").Get())
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get())
    indices = np.asarray(mesh.GetFaceVertexIndicesAttr().Get())
    face_of_corner = np.repeat(np.arange(counts.size), counts)
    np.testing.assert_allclose(vertex[indices], gathered[face_of_corner], rtol=1e-6)
    st = reports["lb"].stats
    # the default is --gather auto: 1024 rays per leaf up to 16k traced leaves
    assert st["gather"]["rays_per_leaf"] == 1024 and st["gather"]["rays"] == 1024 * 1500 and st["gather"]["on"] == "lb"
    assert reports["lb-plain"].stats["gather"] == {"rays_per_leaf": 0} and reports["spp"].stats["gather"]["rays_per_leaf"] == RAYS
    assert st["prototypes"][0]["e_scattered_volume_mean"] != st["prototypes"][0]["e_scattered_mean"]
    assert foliage("validate", d / "lb.usda").returncode == 0


def test_gather_flag_is_checked_before_any_work(tmp_path):
    for cmd in ("lb", "spp"):
        r = foliage(cmd, EXAMPLE, "-o", tmp_path / f"{cmd}.usda", "--gather", "6")
        assert r.returncode == 2 and "multiple of 4" in r.stderr, r.stderr
        assert not (tmp_path / f"{cmd}.usda").exists()


def test_each_volume_records_the_gather_behind_its_per_leaf_light(bakes):
    """``foliage:gatherRays`` (FoliageLightingAPI) says whether ``:scattered`` is gathered, and with how many rays."""
    d, _ = bakes
    for layer, rays in (("lb.usda", 1024), ("lbp.usda", 0), ("spp.usda", RAYS)):
        stage = open_stage(d / layer)
        vol = stage.GetPrimAtPath("/Tree/FoliageLighting")
        assert vol.GetAttribute("foliage:gatherRays").Get() == rays, layer


def test_gather_auto_and_zero_are_accepted_and_a_word_is_refused(tmp_path):
    r = foliage("lb", EXAMPLE, "-o", tmp_path / "lb.usda", "--gather", "seven")
    assert r.returncode == 2 and "neither 'auto' nor a whole number" in r.stderr, r.stderr
    assert "auto|N" in foliage("bake", "--help").stdout
