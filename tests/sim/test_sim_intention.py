"""The patient's intention (sim.intention): each regime's statistics, seeded; bad settings refused at load."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from config import ConfigError, default_config_path, load_config, with_overrides
from sim.intention import Intention

CFG = load_config(default_config_path())
INTENTION = CFG.sim.patient.intention


def _intentions(n: int = 4000, seed: int = 0, **changes) -> np.ndarray:
    """(n, 2): each step's placement ahead of the reference and its lean's X_CoM/X_SP."""
    intention = Intention(dataclasses.replace(INTENTION, **changes), np.random.default_rng(seed))
    return np.array([(i.ahead_m, i.lean_x) for i in (intention.next() for _ in range(n))])


def _draws(n: int = 4000, seed: int = 0, **changes) -> np.ndarray:
    """The placements alone."""
    return _intentions(n, seed, **changes)[:, 0]


def _lag1(x: np.ndarray) -> float:
    d = x - x.mean()
    return float(d[1:] @ d[:-1] / (d @ d))


def test_steady_is_always_the_mean_placement():
    assert set(_draws(50, regime="steady", ahead_m=0.3).tolist()) == {0.3}


def test_noisy_is_gaussian_white_noise_of_the_configured_spread():
    x = _draws(regime="noisy", ahead_m=0.35, spread_m=0.08)
    assert x.mean() == pytest.approx(0.35, abs=0.005)
    assert x.std() == pytest.approx(0.08, rel=0.05)
    assert abs(_lag1(x)) < 0.05  # white: no memory from step to step


def test_the_noisy_lean_is_gaussian_white_noise_independent_of_the_placement():
    both = _intentions(regime="noisy", ahead_m=0.35, spread_m=0.08, lean_x=0.6, lean_spread=0.1)
    lean = both[:, 1]
    assert lean.mean() == pytest.approx(0.6, abs=0.006)
    assert lean.std() == pytest.approx(0.1, rel=0.05)
    assert abs(_lag1(lean)) < 0.05
    assert abs(np.corrcoef(both[:, 0], lean)[0, 1]) < 0.05  # its own draw


def test_steady_and_obstacle_lean_to_the_mean_x():
    for regime in ("steady", "obstacle"):
        assert set(_intentions(50, regime=regime, lean_x=0.6)[:, 1].tolist()) == {0.6}


def test_drifting_wanders_slowly_with_the_configured_spread():
    x = _draws(20000, regime="drifting", ahead_m=0.35, spread_m=0.06, drift_steps=8.0)
    assert x.std() == pytest.approx(0.06, rel=0.1)
    assert _lag1(x) == pytest.approx(np.exp(-1 / 8), abs=0.03)  # consecutive steps alike: a pace, not noise


def test_obstacle_is_now_and_then_a_short_or_long_placement():
    x = _draws(regime="obstacle", ahead_m=0.35, obstacle_probability=0.2, obstacle_offset_m=0.15)
    assert set(np.round(x, 9).tolist()) == {0.2, 0.35, 0.5}
    assert np.mean(x != 0.35) == pytest.approx(0.2, abs=0.02)
    assert np.mean(x < 0.35) == pytest.approx(np.mean(x > 0.35), abs=0.02)


@pytest.mark.parametrize("regime", ["steady", "noisy", "drifting", "obstacle"])
def test_the_same_seed_gives_the_same_intentions(regime):
    assert np.array_equal(_intentions(30, 5, regime=regime), _intentions(30, 5, regime=regime))
    if regime != "steady":
        assert not np.array_equal(_intentions(30, 5, regime=regime), _intentions(30, 6, regime=regime))


@pytest.mark.parametrize("key, value, message", [
    ("sim.patient.intention.spread_m", -0.05, "sim.patient.intention.spread_m: -0.05 is below the minimum 0"),
    ("sim.patient.intention.regime", "wandering", "sim.patient.intention.regime"),
    ("sim.patient.intention.obstacle_probability", 1.5, "sim.patient.intention.obstacle_probability: 1.5 is above the maximum 1"),
])
def test_invalid_intention_settings_fail_at_load_naming_the_key(key, value, message):
    with pytest.raises(ConfigError) as info:
        with_overrides(CFG, {key: value})
    assert message in str(info.value) and "\n" not in str(info.value)
