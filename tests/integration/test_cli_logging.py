"""``-v`` / ``-vv``: the stages and solvers log their choices and timings on stderr; stdout is untouched.

Issue #20: "logging in stages and solvers so -v shows solver choices, sweeps and timings". What would be false if
the logging were wrong: the lines name the stage, the solver and its sweeps; ``--json`` stdout is the same one
JSON object with or without ``-v`` (a log line there would break every pipeline that parses it); ``-vv`` opens the
tool's own loggers only, not the root logger (where numba logs every compilation at DEBUG: 56 lines for a one-line
function; the check sees them only when a kernel compiles in this run, not when numba's cache has it).
"""

from __future__ import annotations

import json

from tests.helpers.cli import REPO, foliage

EXAMPLE = REPO / "examples" / "tree_small.usda"
EXAMPLE_ARGS = ("--resolution", "16", "--gather", "0")


def test_verbose_logs_the_solver_on_stderr_and_leaves_the_json_alone(tmp_path):
    quiet = foliage("lb", EXAMPLE, "-o", tmp_path / "a.usda", *EXAMPLE_ARGS, "--json")
    loud = foliage("lb", EXAMPLE, "-o", tmp_path / "b.usda", *EXAMPLE_ARGS, "--json", "-vv")
    assert quiet.returncode == 0 and loud.returncode == 0, loud.stderr
    a, b = json.loads(quiet.stdout), json.loads(loud.stdout)
    assert a["stats"]["iterations"] == b["stats"]["iterations"] and a["stats"]["solver"] == b["stats"]["solver"]
    assert "INFO" not in quiet.stderr
    lines = loud.stderr.splitlines()
    stage = [ln for ln in lines if ln.startswith("INFO foliage_tools.pipeline.lb:")]
    assert len(stage) == 1 and f"{b['stats']['iterations']} sweeps" in stage[0] and b["stats"]["solver"] in stage[0]
    assert any(ln.startswith("DEBUG foliage_tools.lighting.lb: lb solve:") for ln in lines)
    assert any(ln.startswith("INFO foliage_tools.pipeline.direct: direct:") for ln in lines)
    assert not any("numba" in ln for ln in lines), [ln for ln in lines if "numba" in ln][:3]
