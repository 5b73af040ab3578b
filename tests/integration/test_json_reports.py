"""Every ``--json`` report matches schemas/json/report.schema.json (the contract other tools parse), and its stats
have exactly the keys and kinds of values its ``pipeline.stats`` type declares (what mypy checks the CLI against)."""

import json

import jsonschema
import pytest

from tests.helpers.cli import REPORT_SCHEMA as SCHEMA
from tests.helpers.cli import foliage
from tests.helpers.typed_json import assert_typed_stats


@pytest.mark.parametrize("command", ["inspect", "validate", "plan", "density", "smax", "reference", "bench", "lb", "spp"])
def test_json_report_matches_schema(command, simple_tree, tmp_path):
    args = [command, simple_tree, "--json"]
    if command == "density":
        args += ["-o", tmp_path / "d.usda", "--resolution", "8"]
    if command == "smax":
        args += ["-o", tmp_path / "s.usda"]
    if command == "spp":
        args += ["-o", tmp_path / "p.usda", "--resolution", "8"]
    if command == "lb":
        args += ["-o", tmp_path / "l.usda", "--resolution", "8"]
    if command == "reference":
        args += ["-o", tmp_path / "r.usda", "--paths", "20000"]
    if command == "bench":
        args += ["--paths", "20000", "--plot", tmp_path / "b.png"]
    r = foliage(*args)
    assert r.returncode == 0, r.stderr
    report = json.loads(r.stdout)  # stdout holds the JSON object and nothing else
    jsonschema.validate(report, SCHEMA)
    assert report["command"] == command
    assert_typed_stats(report)


def test_schema_rejects_a_report_missing_stats():
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({"command": "inspect", "version": "0", "inputs": [], "outputs": [], "seconds": 0, "warnings": []}, SCHEMA)
