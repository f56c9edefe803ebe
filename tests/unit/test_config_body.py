"""``aider-exo config body``: the controller's body model for a patient's mass and height, as YAML
that drops into a configuration; the reference patient gives the packaged one back."""

from __future__ import annotations

import json

import pytest
import yaml

from config import default_config_path, load_config
from tests.conftest import ROOT
from tools.cli import main


def _body(capsys, *argv: str) -> dict:
    assert main(["config", "body", *argv]) == 0
    return yaml.safe_load(capsys.readouterr().out)["controller"]


def _close(got, want, tol=1e-3):
    if isinstance(want, (list, tuple)):
        return all(_close(g, w, tol) for g, w in zip(got, want, strict=True))
    return abs(got - want) <= tol


def test_the_reference_patient_gives_the_packaged_body_model(capsys):
    got = _body(capsys, "--mass", "70", "--height", "1.75")
    packaged = load_config(default_config_path()).controller
    for section in ("legs", "body"):
        want = getattr(packaged, section)
        for key, value in got[section].items():
            assert _close(value, getattr(want, key)), (section, key, value, getattr(want, key))


def test_its_yaml_drops_into_a_configuration_that_config_check_accepts(capsys, tmp_path):
    got = _body(capsys, "--mass", "95", "--height", "1.62", "--stick-length", "0.8")
    site = yaml.safe_load((ROOT / "config" / "default.yaml").read_text())
    site["controller"]["legs"].update(got["legs"])
    site["controller"]["body"].update(got["body"])
    path = tmp_path / "patient.yaml"
    path.write_text(yaml.safe_dump(site, sort_keys=False))
    assert main(["config", "check", str(path)]) == 0
    assert load_config(path).controller.body.trunk_kg == got["body"]["trunk_kg"]


def test_a_taller_heavier_patient_has_longer_legs_and_a_heavier_trunk(capsys):
    small = _body(capsys, "--mass", "55", "--height", "1.60")
    large = _body(capsys, "--mass", "100", "--height", "1.95")
    assert large["legs"]["thigh_m"] > small["legs"]["thigh_m"] and large["legs"]["shank_m"] > small["legs"]["shank_m"]
    assert large["body"]["trunk_kg"] > small["body"]["trunk_kg"] and large["body"]["elbow_to_tip_m"] > small["body"]["elbow_to_tip_m"]


def test_json_names_the_patient_its_step_bounds_in_metres_and_its_swing_in_seconds(capsys):
    assert main(["config", "body", "--mass", "70", "--height", "1.75", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["mass_kg"] == 70 and out["height_m"] == 1.75 and set(out["controller"]) == {"legs", "body"}
    assert out["step_m"]["leg_length"] == pytest.approx(0.927, abs=1e-3) and out["step_m"]["init"] == pytest.approx(0.150, abs=1e-3)
    assert main(["config", "body", "--mass", "60", "--height", "1.55", "--json"]) == 0
    short_out = json.loads(capsys.readouterr().out)
    short, leg_ratio = short_out["step_m"], short_out["step_m"]["leg_length"] / out["step_m"]["leg_length"]
    assert short["max"] / out["step_m"]["max"] == pytest.approx(leg_ratio, rel=1e-3)
    assert short_out["swing_s"] / out["swing_s"] == pytest.approx(leg_ratio**0.5, abs=2e-3)  # to the millisecond


@pytest.mark.parametrize("argv, says", [
    (["--mass", "70", "--height", "2.5"], "aider-exo: error: --height: 2.5 is above the maximum 2.1"),
    (["--mass", "300", "--height", "1.8"], "aider-exo: error: --mass: 300.0 is above the maximum 160.0"),
    (["--mass", "70", "--height", "1.75", "--stick-length", "5"], "aider-exo: error: --stick-length: 5.0 is above the maximum 1.5"),
])
def test_a_patient_out_of_the_models_range_is_one_line_naming_the_option(argv, says, capsys):
    assert main(["config", "body", *argv]) == 1
    err = capsys.readouterr().err
    assert err.startswith(says) and err.count("\n") == 1


def test_a_configuration_without_the_anthropometric_model_is_one_line(tmp_path, capsys):
    site = yaml.safe_load((ROOT / "config" / "default.yaml").read_text())
    del site["sim"], site["nodes"]
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(site, sort_keys=False))
    assert main(["config", "body", "--mass", "70", "--height", "1.75", "--config", str(path)]) == 1
    err = capsys.readouterr().err
    assert "sim" in err and "leave out --config" in err and err.count("\n") == 1
