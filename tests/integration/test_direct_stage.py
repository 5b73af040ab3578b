"""Exact direct sunlight in every bake (``--direct rays``, the default) and the volume estimates (``--direct volume``)."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from foliage_tools.lighting.optics import parse_leaf_optics
from foliage_tools.pipeline.direct import DirectChoice, bake_direct
from foliage_tools.pipeline.lb import LBBakeParams, run_lb
from foliage_tools.pipeline.report import Silent
from foliage_tools.pipeline.smax import SmaxParams, run_smax
from foliage_tools.pipeline.spp import SppParams, run_spp
from foliage_tools.pipeline.stage import begin_bake
from tests.helpers.cli import foliage

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "tree_small.usda"
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "examples"))


def _leaf_primvar(layer: Path, name: str, mesh="/Tree/Leaves") -> np.ndarray:
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(layer))
    return np.asarray(UsdGeom.PrimvarsAPI(stage.GetPrimAtPath(mesh)).GetPrimvar(name).Get())


@pytest.fixture(scope="module")
def bakes(tmp_path_factory):
    """smax, spp and lb of the example with the default direct term, and smax with --direct volume."""
    d = tmp_path_factory.mktemp("direct")
    optics = parse_leaf_optics(None)
    out = {
        "smax": run_smax(EXAMPLE, d / "smax.usda", SmaxParams(optics=optics)),
        "spp": run_spp(EXAMPLE, d / "spp.usda", SppParams(optics=optics, resolution=16, depth="grid")),
        "lb": run_lb(EXAMPLE, d / "lb.usda", LBBakeParams(optics=optics, resolution=16)),
        "smax-volume": run_smax(EXAMPLE, d / "smaxv.usda", SmaxParams(optics=optics, direct=DirectChoice(mode="volume"))),
    }
    return d, out


def test_every_bake_writes_the_same_exact_direct_light(bakes):
    d, reports = bakes
    _, scene, sun = begin_bake("smax", EXAMPLE, None, None, Silent())
    exact = bake_direct(scene, sun, DirectChoice(), Silent())
    # per face: every face of a leaf holds the leaf's value (primvars are uniform)
    faces = scene.prototypes[0].leaves.face_leaf_ids[[m.is_leaf for m in scene.prototypes[0].meshes].index(True)]
    expected = exact.per_prototype[0][faces]
    for layer, name in (("smax.usda", "foliage:smax:direct"), ("spp.usda", "foliage:spp:direct"),
                        ("spp.usda", "foliage:sppg:direct"), ("spp.usda", "foliage:ss:direct"), ("lb.usda", "foliage:lb:direct")):
        np.testing.assert_allclose(_leaf_primvar(d / layer, name), expected, rtol=1e-6, atol=1e-7, err_msg=name)
    for m in ("smax", "spp", "lb"):
        st = reports[m].stats["direct"]
        assert st["mode"] == "rays" and st["samples_per_leaf"] == 1024 and 0 < st["noise_rel"] < 0.02
    # and the volume estimate is another number: the old per-method direct, kept for comparison
    volume = _leaf_primvar(d / "smaxv.usda", "foliage:smax:direct")
    assert reports["smax-volume"].stats["direct"] == {"mode": "volume"}
    assert np.linalg.norm(volume - expected) > 0.1 * np.linalg.norm(expected)


def test_direct_flags_on_the_command_line(tmp_path):
    r = foliage("smax", EXAMPLE, "-o", tmp_path / "a.usda", "--direct", "volume", "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["stats"]["direct"]["mode"] == "volume"
    r = foliage("smax", EXAMPLE, "-o", tmp_path / "b.usda", "--direct-samples", "8", "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["stats"]["direct"]["samples_per_leaf"] == 8
    r = foliage("smax", EXAMPLE, "-o", tmp_path / "c.usda", "--direct-samples", "7")
    assert r.returncode == 2 and "--direct-samples" in r.stderr and "even" in r.stderr
    assert not (tmp_path / "c.usda").exists()
    r = foliage("lb", EXAMPLE, "-o", tmp_path / "d.usda", "--direct", "shadows")
    assert r.returncode == 2 and "rays" in r.stderr


def test_uniform_layer_through_usd_matches_beer_lambert(tmp_path):
    # A new user's layer (examples/make_layer.py, the 10 x 10 x 1.5 m, 30 000 cards, LAI 3,
    # sun at elevation 60°) through `foliage smax` with its default direct term: per depth bin of the
    # inner region the leaves' E_direct is Beer-Lambert's |n·s| exp(-τ/μ0) within 2 % (the bound and its
    # reason: tests/unit/test_direct.py::test_uniform_layer_against_beer_lambert; the layer's read
    # back from USD here, leaf ids, order and all).
    from make_layer import build_layer, write_layer_stage

    g = build_layer(seed=1)
    path = write_layer_stage(tmp_path / "layer.usda", g, sun=(0.0, 60.0))
    out = tmp_path / "layer.smax.usda"
    report = run_smax(path, out, SmaxParams(optics=parse_leaf_optics("0.45,0.45")))
    e = _leaf_primvar(out, "foliage:smax:direct", mesh="/Layer/Leaves")[:, 0]  # one face per card, in card order
    el = math.radians(60.0)
    sun = np.array([math.cos(el), 0.0, math.sin(el)])
    tau = 0.5 * 3.0 * (1.5 - g.centres[:, 2]) / 1.5
    expected = np.abs(g.normals @ sun) * np.exp(-tau / sun[2])
    inner = (np.abs(g.centres[:, 0]) < 4) & (np.abs(g.centres[:, 1]) < 4)
    bins = np.clip(np.digitize(tau, np.linspace(0, 1.5, 6)) - 1, 0, 4)
    dev = np.array([e[inner & (bins == k)].sum() / expected[inner & (bins == k)].sum() - 1 for k in range(5)])
    assert np.all(np.abs(dev) < 0.02), dev
    assert report.stats["direct"]["mode"] == "rays"
