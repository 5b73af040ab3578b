"""``--gather auto``: the rays per leaf it picks for a scene, and when it turns the gather off."""

from __future__ import annotations

import pytest

from foliage_tools.errors import UsageError
from foliage_tools.pipeline.gather import AUTO_MAX, AUTO_MIN, AUTO_RAY_BUDGET, auto_rays, check_gather, resolve_rays


@pytest.mark.parametrize("leaves", [1, 441, 1500, 16_384, 16_385, 40_000, 100_000, 262_144, 262_145, 10**6])
def test_auto_is_the_largest_power_of_two_within_the_ray_budget(leaves):
    k = auto_rays(leaves)
    if leaves * AUTO_MIN > AUTO_RAY_BUDGET:  # not even the fewest rays that pay fit: off
        assert k == 0
        return
    assert AUTO_MIN <= k <= AUTO_MAX and k & (k - 1) == 0  # a power of two, so a multiple of 4
    assert k * leaves <= AUTO_RAY_BUDGET or k == AUTO_MIN
    assert k == AUTO_MAX or 2 * k * leaves > AUTO_RAY_BUDGET  # and the largest such
    check_gather(k)


def test_the_budget_boundaries():
    # 2^24 rays: 1024 per leaf up to 16k leaves, 64 at 256k, off beyond
    assert auto_rays(16_384) == 1024 and auto_rays(16_385) == 512
    assert auto_rays(262_144) == 64 and auto_rays(262_145) == 0


def test_resolve_keeps_an_explicit_count_and_warns_when_auto_turns_the_gather_off():
    warnings: list[str] = []
    assert resolve_rays(256, 10**7, warnings) == 256 and resolve_rays(0, 1500, warnings) == 0 and not warnings
    assert resolve_rays(None, 1500, warnings) == 1024 and not warnings
    assert resolve_rays(None, 10**6, warnings) == 0
    assert len(warnings) == 1 and "1,000,000 traced leaves" in warnings[0] and f"--gather {AUTO_MIN}" in warnings[0]


@pytest.mark.parametrize("rays", [-4, 2, 6, 1 << 17])
def test_bad_counts_are_usage_errors(rays):
    with pytest.raises(UsageError, match="multiple of 4"):
        check_gather(rays)
