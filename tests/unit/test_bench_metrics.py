"""Error measures used by ``foliage bench``."""

import numpy as np
import pytest

from foliage_tools.bench.metrics import binned_rms, noise_floor, rel_rms


def test_rel_rms_closed_forms():
    r = np.array([1.0, 2.0, 2.0])
    assert rel_rms(r, r) == 0.0
    assert rel_rms(1.1 * r, r) == pytest.approx(0.1)
    assert rel_rms(np.zeros(3), r) == pytest.approx(1.0)
    assert rel_rms(np.zeros(3), np.zeros(3)) == 0.0
    assert rel_rms(np.ones(3), np.zeros(3)) == float("inf")
    with pytest.raises(ValueError):
        rel_rms(np.ones(3), np.ones(4))


def test_binned_rms_forgives_noise_within_a_class_but_not_a_bias(rng):
    n = 4000
    depth = rng.uniform(0, 5, n)
    width = depth + rng.uniform(0, 5, n)
    ref = np.exp(-depth)[:, None] * np.ones((1, 3))
    # zero-mean scatter within each class: the class averages barely move
    noisy = ref * (1 + 0.3 * rng.choice([-1.0, 1.0], size=(n, 1)))
    assert binned_rms(noisy, ref, depth, width) < 0.1 < rel_rms(noisy, ref)
    # a uniform 20 % bias survives averaging
    assert binned_rms(1.2 * ref, ref, depth, width) == pytest.approx(0.2, rel=1e-9)


def test_noise_floor_estimates_the_full_run_noise(rng):
    # two halves with relative noise sigma*sqrt(2) each: the full run has sigma
    truth = rng.uniform(1, 2, 20000)
    sigma = 0.05
    a = truth * (1 + sigma * np.sqrt(2) * rng.standard_normal(truth.size))
    b = truth * (1 + sigma * np.sqrt(2) * rng.standard_normal(truth.size))
    full = 0.5 * (a + b)
    assert noise_floor(a, b) == pytest.approx(rel_rms(full, truth), rel=0.05)
