"""Leaf optics presets and parsing (foliage_tools.lighting.optics)."""

import numpy as np
import pytest

from foliage_tools.lighting.optics import LeafOptics, parse_leaf_optics


def test_geist2008_preset_reproduces_table1_g():
    # geist2008 Table 1 lists g = (-0.120, 0.091, -0.333), derived from f_s and b_s by eq. (10)
    optics = parse_leaf_optics(None)
    np.testing.assert_allclose(optics.g, [-0.120, 0.091, -0.333], atol=5e-4)


@pytest.mark.parametrize(
    "spec, r, t",
    [("0.1,0.2", [0.1] * 3, [0.2] * 3), ("0.1,0.2,0.3,0.05,0.1,0.15", [0.1, 0.2, 0.3], [0.05, 0.1, 0.15])],
)
def test_parse_numbers(spec, r, t):
    o = parse_leaf_optics(spec, wood_reflectance=0.3)
    np.testing.assert_allclose(o.reflectance, r)
    np.testing.assert_allclose(o.transmittance, t)
    np.testing.assert_allclose(o.wood_reflectance, 0.3)


@pytest.mark.parametrize("spec", ["nonsense", "0.1", "0.6,0.6", "1,2,3", "-0.1,0.2"])
def test_bad_specs_raise_with_the_flag_name_or_reason(spec):
    with pytest.raises(ValueError):
        parse_leaf_optics(spec)


def test_optics_arrays_are_immutable():
    o = LeafOptics(0.1, 0.1)
    with pytest.raises(ValueError):
        o.reflectance[0] = 0.5


def test_a_preset_name_in_any_case():
    # `--leaf-optics Bright` was refused as not a preset (a new user's trial)
    for spec, name in (("Bright", "bright"), ("GEIST2008", "geist2008")):
        a, b = parse_leaf_optics(spec), parse_leaf_optics(name)
        np.testing.assert_array_equal(a.reflectance, b.reflectance)
        np.testing.assert_array_equal(a.transmittance, b.transmittance)
