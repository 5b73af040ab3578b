"""``foliage bake``'s summary lists the exact direct light it traces before the stages, with its seconds.

The direct light (``--direct rays``, the default) is traced once for smax, spp and lb, before any of them, so it
is in none of the stages' seconds; a summary without it did not add up to the bake's time. Run through click's
runner on a fake pipeline report, so nothing is baked.
"""

from __future__ import annotations

from pathlib import Path

from click.testing import CliRunner

from foliage_tools.cli.main import cli
from foliage_tools.pipeline.report import Report

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "tree_small.usda"
STAGES = ("density", "smax", "spp", "lb", "preview")


def _fake_bake(direct: dict):
    def run_bake(path, outdir, params, *, progress=None) -> Report:
        stats = {"result": str(Path(outdir) / "tree_small.lb.usda"), "bench": None, "direct": direct,
                 "stages": {name: {"seconds": 0.5, "outputs": [], "peak_rss_bytes": None} for name in STAGES}}
        return Report(command="bake", inputs=[str(path)], stats=stats)

    return run_bake


def test_summary_lists_the_direct_step_first(monkeypatch, tmp_path):
    import foliage_tools.pipeline.bake as bake_module

    direct = {"mode": "rays", "samples_per_leaf": 1024, "rays": 1_536_000, "seconds": 1.27, "noise_rel": 0.006, "leaves": 1500}
    monkeypatch.setattr(bake_module, "run_bake", _fake_bake(direct))
    result = CliRunner().invoke(cli, ["bake", str(EXAMPLE), "-o", str(tmp_path / "out")])
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    assert lines[0].split() [:3] == ["direct:", "1.27", "s"], result.output
    assert "1,024 shadow rays per leaf" in lines[0]
    assert [line.split(":")[0].strip() for line in lines[1:6]] == list(STAGES)


def test_no_direct_step_with_direct_volume(monkeypatch, tmp_path):
    import foliage_tools.pipeline.bake as bake_module

    monkeypatch.setattr(bake_module, "run_bake", _fake_bake({"mode": "volume"}))
    result = CliRunner().invoke(cli, ["bake", str(EXAMPLE), "-o", str(tmp_path / "out"), "--direct", "volume"])
    assert result.exit_code == 0, result.output
    assert "direct:" not in result.output and result.output.splitlines()[0].split(":")[0].strip() == "density"
