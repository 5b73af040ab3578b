"""``pipeline.stats`` against the JSON contract: every key the schema promises a consumer is declared in its command's
``TypedDict`` (so mypy holds the code to it), and the run-time checker the integration tests use can fail."""

import json

import pytest

from tests.helpers.cli import REPORT_SCHEMA
from tests.helpers.typed_json import STATS_TYPES, problems


def _schema_stats() -> dict[str, dict]:
    """command -> the schema's ``stats`` object for it (``else.allOf[i]``: if command == X then stats ...)."""
    out = {}
    for branch in REPORT_SCHEMA["else"]["allOf"]:
        command = branch["if"]["properties"]["command"]["const"]
        out[command] = branch["then"]["properties"]["stats"]
    return out


def test_every_command_the_schema_knows_has_a_stats_type():
    commands = set(REPORT_SCHEMA["properties"]["command"]["enum"]) - {"foliage"}  # "foliage": error reports only
    assert commands == set(STATS_TYPES)


@pytest.mark.parametrize("command", sorted(_schema_stats()))
def test_the_schema_s_required_stats_keys_are_required_in_the_type(command):
    required = set(_schema_stats()[command].get("required", []))
    tp = STATS_TYPES[command]
    assert required <= tp.__required_keys__, f"{command}: the schema requires {sorted(required - tp.__required_keys__)}"


DENSITY = {"method": "area", "prototypes": [{
    "path": "/Tree", "volume": "/Tree/FoliageLighting", "leaves": 3, "shape": [4, 4, 4], "voxel_size": 0.5,
    "origin": [0, 0, 0.0], "active_voxels": 2, "leaf_area_mesh": 1.5, "leaf_area_grid": None, "area_rel_error": None,
    "seconds": 0.1}]}


def test_a_well_formed_report_passes():
    assert problems(json.loads(json.dumps(DENSITY)), STATS_TYPES["density"]) == []


@pytest.mark.parametrize("mutate, expected", [
    (lambda d: d.pop("method"), "missing key 'method'"),
    (lambda d: d.update(extra=1), "key 'extra' is not declared"),
    (lambda d: d["prototypes"][0].update(leaves=3.5), "stats.prototypes[0].leaves: 3.5, expected an int"),
    (lambda d: d["prototypes"][0].update(leaves=True), "expected an int"),  # a bool is not a count
    (lambda d: d["prototypes"][0].update(shape="4x4x4"), "expected a list"),
    (lambda d: d["prototypes"][0].update(area_rel_error="n/a"), "is none of"),
    (lambda d: d["prototypes"][0].pop("volume"), "missing key 'volume'"),
])
def test_the_checker_finds_what_is_wrong(mutate, expected):
    d = json.loads(json.dumps(DENSITY))
    mutate(d)
    found = problems(d, STATS_TYPES["density"])
    assert any(expected in f for f in found), found
