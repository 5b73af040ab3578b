"""``smax`` reports the recollision probability p only where it is used: ``--scatter leaves`` counts the higher
orders of scattering by it (boulanger.higher_orders); ``--scatter paper``, the thesis' one bounce, uses no p and
reports null. The JSON schema says so, and holds either report to it."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import jsonschema
import pytest

from foliage_tools.lighting.optics import parse_leaf_optics
from foliage_tools.pipeline.direct import DirectChoice
from foliage_tools.pipeline.smax import SmaxParams, run_smax

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "examples" / "tree_small.usda"
SCHEMA = json.loads((REPO / "schemas" / "json" / "report.schema.json").read_text())


def _report(tmp_path: Path, scatter: str) -> dict:
    params = SmaxParams(optics=parse_leaf_optics(None), scatter=scatter, direct=DirectChoice(mode="volume"))
    return json.loads(json.dumps(run_smax(EXAMPLE, tmp_path / f"t.{scatter}.usda", params).as_json()))


def test_paper_reports_no_recollision_probability(tmp_path):
    report = _report(tmp_path, "paper")
    (proto,) = report["stats"]["prototypes"]
    assert proto["scatter"] == "paper" and proto["recollision_probability"] is None
    jsonschema.validate(report, SCHEMA)
    wrong = copy.deepcopy(report)
    wrong["stats"]["prototypes"][0]["recollision_probability"] = 0.52
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(wrong, SCHEMA)


def test_leaves_reports_the_p_it_used(tmp_path):
    report = _report(tmp_path, "leaves")
    (proto,) = report["stats"]["prototypes"]
    assert proto["scatter"] == "leaves" and 0.0 < proto["recollision_probability"] < 1.0
    jsonschema.validate(report, SCHEMA)
    wrong = copy.deepcopy(report)
    wrong["stats"]["prototypes"][0]["recollision_probability"] = None
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(wrong, SCHEMA)
