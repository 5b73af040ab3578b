"""A solver's non-finite field is our bug, not the user's input: exit 3 with a crash log (DESIGN.md section 3).

``lighting.lb.LBNumericalError`` used to be a FoliageError carrying exit code 3, so the command line printed it as
an input error and exited 3 *without* the crash log the contract promises for internal failures (issue #20). Run
through click's runner with the solver made to fail, so nothing is baked.
"""

from __future__ import annotations

from pathlib import Path

from click.testing import CliRunner

from foliage_tools.cli.main import cli
from foliage_tools.errors import EXIT_INTERNAL, FoliageError
from foliage_tools.lighting import lb

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "tree_small.usda"


def test_a_non_finite_lattice_is_an_internal_error_with_a_crash_log(tmp_path, monkeypatch):
    assert not issubclass(lb.LBNumericalError, FoliageError)

    def fail(problem, params=None):
        raise lb.LBNumericalError("the lattice field became non-finite (sweep 7)")

    monkeypatch.setattr(lb, "solve", fail)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    out = tmp_path / "t.lb.usda"
    result = CliRunner().invoke(cli, ["lb", str(EXAMPLE), "-o", str(out), "--resolution", "8", "--gather", "0"])
    assert result.exit_code == EXIT_INTERNAL, result.output
    assert "internal error: LBNumericalError" in result.output and "non-finite" in result.output
    logs = list((tmp_path / "cache" / "foliage-tools").glob("crash-*.log"))
    assert len(logs) == 1 and "LBNumericalError" in logs[0].read_text(encoding="utf-8")
    assert not out.exists()  # nothing written
