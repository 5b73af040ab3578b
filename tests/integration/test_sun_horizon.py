"""Every bake refuses a sun at or below the horizon the same way, before any work: exit 2, the sun named, nothing
written (pipeline.stage.require_sun_above_horizon). Before, spp refused it while lb and smax baked it without a
word and bake failed only at its spp stage (a new user's trial)."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.helpers.cli import foliage

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "tree_small.usda"


@pytest.mark.parametrize("command, out, extra", [
    ("lb", "o.lb.usda", ("--resolution", "8")), ("smax", "o.smax.usda", ()), ("spp", "o.spp.usda", ("--resolution", "8")),
    ("reference", "o.ref.usda", ("--paths", "1000")), ("bake", "bake", ("--resolution", "8")),
])
@pytest.mark.parametrize("sun", ["45,-10", "45,0"])
def test_a_sun_below_the_horizon_is_refused_before_any_work(tmp_path, command, out, extra, sun):
    r = foliage(command, EXAMPLE, "-o", tmp_path / out, "--sun", sun, *extra)
    assert r.returncode == 2, r.stderr
    assert "at or below the horizon" in r.stderr and "--sun" in r.stderr
    assert list(tmp_path.iterdir()) == []  # no output, no staging, no directory
