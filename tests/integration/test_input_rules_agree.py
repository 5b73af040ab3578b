"""One rule, one message: what ``validate`` fails, every bake refuses (exit 2) in the same words, and never crashes
on (exit 3). The inputs are the corpus files of these kinds (tests/corpus/generate.py); before, validate passed
most of them while the bakes crashed, wrote ``inf`` or refused them in other words."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from tests.helpers.cli import foliage

BAD = Path(__file__).resolve().parents[1] / "corpus" / "bad"
FAST = ("--resolution", "8", "--gather", "16", "--direct-samples", "16")

#: corpus files validate fails with findings (exit 1) and the rule whose message the bakes repeat
FINDINGS = {
    "garbage_vdb.usda": "volume-grids",
    "missing_vdb.usda": "volume-grids",
    "meters_per_unit_huge.usda": "stage-units",
    "up_axis_x.usda": "stage-units",
    "sun_below_horizon.usda": "sun",
    "projective_transform.usda": "transforms",
    "tiny_coordinates.usda": "geometry-scale",
    "denormal_coordinates.usda": "geometry-scale",
    "tiny_single_leaf.usda": "geometry-scale",
    "sun_colour_nan.usda": "lights",
    "sun_colour_negative.usda": "lights",
    "dome_intensity_nan.usda": "lights",
    "unknown_attribute_type.usda": "attribute-types",
    "unknown_xform_op.usda": "transforms",
}
#: corpus files no command can open: validate and the bakes refuse them (exit 2) with one message
REFUSED = ("non_utf8_layer.usda", "payload_garbage.usda", "reference_garbage_usdc.usda")


def _strict_json(text: str) -> dict:
    def no_nan(name: str):
        raise AssertionError(f"--json printed {name}, which is not JSON")

    return json.loads(text, parse_constant=no_nan)


@pytest.mark.parametrize("name", sorted(FINDINGS))
def test_the_bake_refuses_what_validate_fails_in_its_words(tmp_path, name):
    v = foliage("validate", name, "--json", cwd=BAD)
    assert v.returncode == 1, v.stdout + v.stderr
    findings = [f for f in _strict_json(v.stdout)["stats"]["findings"] if f["severity"] == "error"]
    said = {f["message"] for f in findings if f["rule"] == FINDINGS[name]}
    assert said, findings
    r = foliage("lb", name, "-o", tmp_path / "out.usda", *FAST, "--json", cwd=BAD)
    assert r.returncode == 2, r.stdout + r.stderr
    error = _strict_json(r.stdout)["error"]["message"]
    assert error.split(" (1 more such problem")[0] in said, (error, said)
    assert not (tmp_path / "out.usda").exists()


@pytest.mark.parametrize("name", REFUSED)
def test_what_no_command_opens_is_exit_2_naming_the_file_everywhere(tmp_path, name):
    messages = set()
    for args in (("validate", name), ("inspect", name), ("lb", name, "-o", tmp_path / "out.usda", *FAST)):
        r = foliage(*args, "--json", cwd=BAD)
        assert r.returncode == 2, r.stdout + r.stderr
        message = _strict_json(r.stdout)["error"]["message"]
        assert name in message and "internal error" not in r.stderr, message
        messages.add(message)
    assert len(messages) == 1, messages


def test_inspect_json_never_prints_nan_for_a_light(tmp_path):
    r = foliage("inspect", "dome_intensity_nan.usda", "--json", cwd=BAD)
    assert r.returncode == 2, r.stdout + r.stderr  # was exit 3, "Out of range float values are not JSON compliant"
    assert "DomeLight </Lights/Sky> has inputs:intensity nan" in _strict_json(r.stdout)["error"]["message"]


def test_a_huge_meters_per_unit_is_never_written_as_inf(tmp_path):
    r = foliage("bake", "meters_per_unit_huge.usda", "-o", tmp_path / "out", *FAST, cwd=BAD)
    assert r.returncode == 2 and "metersPerUnit is 1e+300" in r.stderr, r.stderr
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_the_bound_on_meters_per_unit_is_what_float32_holds():
    """The bound is float32's normal range (the bakes record the unit as a float): its ends round-trip finite."""
    import numpy as np

    from foliage_tools.scene.bakeable import MAX_METERS_PER_UNIT, MIN_METERS_PER_UNIT

    for value in (MIN_METERS_PER_UNIT, MAX_METERS_PER_UNIT):
        stored = float(np.float32(value))
        assert math.isfinite(stored) and stored > 0 and math.isclose(stored, value, rel_tol=1e-7)
    with np.errstate(over="ignore"):
        assert not math.isfinite(float(np.float32(MAX_METERS_PER_UNIT * 2)))
