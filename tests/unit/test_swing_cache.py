"""The cached swing DMP weights: current for the configuration, refused when stale."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from config import default_config_path, load_config
from controller import factory
from controller.dmp import Dmp
from controller.swing import SwingWeightsError, fit_swing, load_swing, save_swing

CFG = load_config(default_config_path()).controller


def test_committed_weights_match_a_fresh_fit():
    cached = load_swing(CFG)
    fresh = fit_swing(CFG)
    assert np.allclose(cached.weights, fresh.weights, atol=1e-9), "stale: run `aider-exo dmp fit`"
    assert cached.tau_s == fresh.tau_s


def test_stale_or_broken_weights_are_refused_with_the_fix(tmp_path):
    path = tmp_path / "w.json"
    with pytest.raises(SwingWeightsError, match="no fitted swing weights; run `aider-exo dmp fit`"):
        load_swing(CFG, path)
    save_swing(CFG, fit_swing(CFG), path)
    other = dataclasses.replace(CFG, swing=dataclasses.replace(CFG.swing, demonstration_step_m=0.12))
    with pytest.raises(SwingWeightsError, match="fitted for another demonstration sha256"):
        load_swing(other, path)
    path.write_text("{not json")
    with pytest.raises(SwingWeightsError, match="unreadable"):
        load_swing(CFG, path)


def test_the_cached_swing_lands_at_the_goal():
    dmp = Dmp(load_swing(CFG))
    tau = factory.swing_duration_s(CFG)
    dmp.reset(x0=np.zeros(2), goal=np.array([0.12, 0.0]), tau_s=tau)
    _, xz = dmp.rollout(0.02, 1.5 * tau, substeps=CFG.swing.substeps)
    assert xz[-1] == pytest.approx([0.12, 0.0], abs=0.002)
    assert xz[:, 1].max() == pytest.approx(CFG.swing.clearance_m, abs=0.01)


def test_cli_fit_writes_the_file(tmp_path, capsys):
    from tools.cli import main

    out = tmp_path / "w.json"
    assert main(["dmp", "fit", "--out", str(out), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["max_reproduction_error_mm"] < 1.0 and out.exists()


def test_factory_builds_the_core_from_the_configuration():
    learner = factory.learner(CFG, np.random.default_rng(0))
    assert learner.theta.tolist() == [CFG.learning.initial_alpha, CFG.learning.initial_xhat]
    assert factory.pi2_params(CFG).noise_std == (CFG.learning.noise_alpha, CFG.learning.noise_xhat)
    assert factory.leg(CFG).reach_m == pytest.approx(CFG.legs.thigh_m + CFG.legs.shank_m)
    assert factory.step_bounds(CFG).init_m == 0.15
