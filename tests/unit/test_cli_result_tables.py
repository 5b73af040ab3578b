"""The result tables of ``foliage bench`` and ``foliage smax`` keep every name and heading whole.

rich fits a table to 80 columns when stdout is not a terminal (a pipe, a CI log) and cuts what does not fit with
an ellipsis: ``sppg-paper-radiance`` became ``sppg-pa…`` and ``E_scattered`` ``E_scatte…``. The commands run
here through click's runner (stdout is not a terminal) on a fake pipeline report, so nothing is traced.
"""

from __future__ import annotations

import io
from pathlib import Path

from click.testing import CliRunner
from rich.console import Console

from foliage_tools.cli import console
from foliage_tools.cli.bakes import bench_table, count
from foliage_tools.cli.main import cli
from foliage_tools.pipeline.report import Report

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "tree_small.usda"
SUN = {"azimuth": 45.0, "elevation": 60.0, "source": "</Lights/Sun>"}
NAMES = ("lb-64-lattice1", "sppg-paper-radiance", "sppg-once", "smax-paper")
HEADINGS = ("rel. RMS E_scattered", "rel. RMS total", "total, own direct", "binned E_scattered (eq. 30)",
            "binned total (eq. 30)")


def _method(name: str) -> dict:
    return {"name": name, "available": True, "seconds": 1.234, "rel_rms_scattered": 0.25, "rel_rms_total": 0.05,
            "rel_rms_total_volume": 0.07, "binned_rms": 0.1, "binned_rms_total": 0.02}


def _bench_stats() -> dict:
    return {
        "leaves": 1500, "sun": SUN,
        "reference": {"paths": 6_710_886, "seconds": 12.5, "noise_rel": 0.0199, "noise_rel_total": 0.008},
        "direct": {"seconds": 2.0, "rel_rms_direct": 0.004},
        "methods": [_method(n) for n in NAMES],
    }


def _fake(command: str, stats: dict):
    def run(*args, **kwargs) -> Report:
        report = Report(command=command, inputs=[str(EXAMPLE)], stats=stats)
        report.seconds = 3.0
        return report

    return run


def test_bench_table_in_a_pipe_keeps_names_and_headings_whole(monkeypatch):
    import foliage_tools.pipeline.bench as bench_module

    monkeypatch.setattr(bench_module, "run_bench", _fake("bench", _bench_stats()))
    result = CliRunner().invoke(cli, ["bench", str(EXAMPLE)])
    assert result.exit_code == 0, result.output
    assert "…" not in result.output
    for text in (*NAMES, *HEADINGS):
        assert text in result.output, f"{text!r} is not whole in\n{result.output}"
    # one line per row: nothing wrapped
    assert any("sppg-paper-radiance" in line and "1.234" in line for line in result.output.splitlines())


def test_bench_reference_row_shows_its_paths(monkeypatch):
    import foliage_tools.pipeline.bench as bench_module

    monkeypatch.setattr(bench_module, "run_bench", _fake("bench", _bench_stats()))
    result = CliRunner().invoke(cli, ["bench", str(EXAMPLE)])
    assert "reference (6.71M paths)" in result.output, result.output
    assert (count(6_710_886), count(64_000_000), count(20_000), count(1500)) == ("6.71M", "64M", "20k", "1,500")


def test_smax_table_in_a_pipe_keeps_headings_and_prim_paths_whole(monkeypatch, tmp_path):
    import foliage_tools.pipeline.smax as smax_module

    path = "/World/FoliageBakes/Prototypes/Tree_with_a_long_name_00"
    proto = {"path": path, "leaves": 1500, "path_used": "reference", "tau": 0.877, "smax_mean": 1.1,
             "e_direct_mean": [0.22] * 3, "e_scattered_mean": [0.03] * 3}
    monkeypatch.setattr(smax_module, "run_smax", _fake("smax", {"sun": SUN, "prototypes": [proto]}))
    result = CliRunner().invoke(cli, ["smax", str(EXAMPLE), "-o", str(tmp_path / "t.smax.usda")])
    assert result.exit_code == 0, result.output
    assert "…" not in result.output
    for text in (path, "mean E_direct (green)", "mean E_scattered (green)", "mean s_max"):
        assert text in result.output, f"{text!r} is not whole in\n{result.output}"


def test_bench_table_on_a_narrow_terminal_keeps_method_names_whole():
    """A terminal has a width: the table fits it, the method names stay on one line, the rest folds (no ellipsis)."""
    term = Console(file=io.StringIO(), width=80, force_terminal=True, color_system=None)
    console.print_table(bench_table(EXAMPLE, _bench_stats()), console=term)
    out = term.file.getvalue()
    assert "…" not in out
    assert max(len(line) for line in out.splitlines()) <= 80
    for name in NAMES:
        assert name in out, out
    assert "reference (6.71M paths)" in out
