"""A bake's warnings say each thing once, in order, however many of its stages said it (pipeline.bake_warnings)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

from foliage_tools.lighting.optics import parse_leaf_optics
from foliage_tools.pipeline import bake as bake_module
from foliage_tools.pipeline.bake import BakeParams, run_bake
from foliage_tools.pipeline.bake_warnings import merge
from foliage_tools.pipeline.leafdata import native_instance_warning
from foliage_tools.pipeline.report import Report

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "tree_small.usda"
TREE = SimpleNamespace(path="/World/T0")
BUSH = SimpleNamespace(path="/World/B0")
PLACED = " Its grids are in the class </World/FoliageBakes/Prototypes/T0>, placed over each of its 4 instance(s)."
SUN = "the sun is below the horizon of <Tree_02>'s frame"


def _stages() -> list[tuple[str, list[str]]]:
    return [
        ("density", [native_instance_warning(TREE, "primvars:foliage:leafId") + PLACED]),
        ("smax", [SUN, native_instance_warning(TREE, "s_max primvars"), native_instance_warning(BUSH, "s_max primvars")]),
        ("spp", [native_instance_warning(TREE, "SPP primvars"), SUN]),
        ("lb", [native_instance_warning(TREE, "LB primvars"), SUN]),
        ("preview", ["every prototype is a native instance, so ... the direct light only"]),
    ]


def test_same_text_once_naming_its_stages_in_order():
    merged = merge(_stages())
    assert len(merged) == 4, merged
    tree, sun, bush, preview = merged
    assert sun == f"smax, spp, lb: {SUN}"
    assert bush == f"smax: {native_instance_warning(BUSH, 's_max primvars')}"  # said by one stage: as it was
    assert preview.startswith("preview: every prototype is a native instance")


def test_a_native_instance_is_one_warning_listing_what_no_stage_could_store():
    tree = merge(_stages())[0]
    assert tree == (
        "density, smax, spp, lb: "
        + native_instance_warning(TREE, "primvars:foliage:leafId, s_max primvars, SPP primvars and LB primvars")
        + PLACED
    )
    assert tree.count("is a native instance") == 1


def test_run_bake_reports_each_warning_once(monkeypatch, tmp_path):
    """run_bake's own wiring, with its stages and commit faked (nothing is baked)."""
    def stages(path, work, params, progress, *, stem, ext="usda"):
        # the one stat run_bake reads of a stage: smax's direct light (the bake's own, in its summary)
        return {name: Report(command=name, inputs=[str(path)], warnings=list(w),
                             stats={"direct": {"mode": "volume"}} if name == "smax" else {}) for name, w in _stages()}

    def commit(path, outdir, commit, *, portable_input=None):
        return {"tree_small.lb.usda": Path(outdir) / "tree_small.lb.usda"}

    monkeypatch.setattr(bake_module, "_run_stages", stages)
    monkeypatch.setattr(bake_module, "_commit", commit)
    report = run_bake(EXAMPLE, tmp_path / "out", BakeParams(optics=parse_leaf_optics(None), resolution=8))
    assert report.warnings == merge(_stages())
    assert sum("is a native instance:" in w for w in report.warnings) == 2  # one per prototype
