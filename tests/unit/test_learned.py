"""Per-learned files (controller/learned.py): the theta to walk with and the learner state round
trip; every unusable name or file is a one-line LearnedError naming the file (never a traceback,
never a silent fall-back to the defaults); the saver writes off the tick and close() flushes."""

from __future__ import annotations

import json
import math
import threading

import numpy as np
import pytest

from config import default_config_path, load_config, with_overrides
from config.errors import AiderError
from controller import factory, learned
from controller.pi2 import learner_state
from controller.learned import (
    LearnedError,
    LearnedSaver,
    load_learned,
    learned_path,
    restore_learner,
    save_learned,
)

BASE = load_config(default_config_path())
# Small roll-outs so that a learner with an update is cheap to make.
SMALL = with_overrides(BASE, {"controller.learning.steps_per_rollout": 2, "controller.learning.rollouts_per_update": 2})


def learner_with_an_update(seed: int = 3):
    """A learner that has run one update (two roll-outs of two gait cycles) and is one roll-out
    into the next batch, so its state has history and a waiting batch."""
    pi2 = factory.learner(SMALL.controller, np.random.default_rng(seed))
    for costs in ((60.0, 62.0), (55.0, 57.0), (58.0, 59.0)):
        pi2.ask()
        for c in costs:
            pi2.tell_step(c)
        pi2.end_rollout(False)
    assert pi2.n_updates == 1 and pi2.rollouts_in_batch == 1
    return pi2


def valid_file(**changes) -> dict:
    data = {"format": learned.FORMAT, "version": learned.VERSION, "patient": "p", "x_ratio": learned.X_RATIO,
            "theta": [-0.5, 0.6], "learner": None}
    data.update(changes)
    return data


def as_json(data):
    """``data`` as it reads back from a JSON file (tuples become lists)."""
    return json.loads(json.dumps(data))


def assert_one_line_naming(exc: BaseException, path) -> None:
    text = str(exc)
    assert isinstance(exc, AiderError)
    assert str(path) in text, text
    assert "\n" not in text, text


# -- round trip --------------------------------------------------------------------------------


def test_a_patient_file_round_trips_theta_and_the_learner_state(tmp_path):
    pi2 = learner_with_an_update()
    theta = pi2.evaluation_theta()
    path = save_learned(tmp_path / "patients", "anna-1", theta, pi2)  # the folder is created
    assert path == tmp_path / "patients" / "anna-1.json"
    data = json.loads(path.read_text())
    assert data["format"] == learned.FORMAT and data["version"] == learned.VERSION and data["patient"] == "anna-1"
    assert data["x_ratio"] == learned.X_RATIO  # the X_CoM/X_SP theta was learned on
    assert [p.name for p in path.parent.iterdir()] == ["anna-1.json"]  # written atomically: no temporary file left

    record = load_learned(tmp_path / "patients", "anna-1")
    assert record.name == "anna-1"
    assert record.theta == tuple(float(v) for v in theta)
    restored = restore_learner(record, np.random.default_rng(0), path)
    assert learner_state(restored) == learner_state(pi2)
    assert restored.n_updates == 1 and restored.rollouts_in_batch == 1
    np.testing.assert_array_equal(restored.evaluation_theta(), theta)


def test_a_file_without_a_learner_round_trips_its_theta(tmp_path):
    save_learned(tmp_path, "b", (-3.25, 0.71), None)
    record = load_learned(tmp_path, "b")
    assert record.theta == (-3.25, 0.71) and record.learner_state is None
    assert restore_learner(record, np.random.default_rng(0), tmp_path / "b.json") is None


def test_a_patient_without_a_file_has_no_record(tmp_path):
    assert load_learned(tmp_path, "nobody") is None
    assert load_learned(tmp_path / "missing-folder", "nobody") is None
    assert not (tmp_path / "nobody.json").exists()


# -- names -------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["", "../etc", "a/b", ".hidden", "-x", "a b", "abc\n", "x" * 65, "é"])
def test_a_bad_patient_name_is_an_error(tmp_path, name):
    for call in (lambda: learned_path(tmp_path, name), lambda: load_learned(tmp_path, name),
                 lambda: save_learned(tmp_path, name, (0.0, 0.5), None)):
        with pytest.raises(LearnedError) as info:
            call()
        assert repr(name) in str(info.value) and "\n" not in str(info.value)
    assert list(tmp_path.iterdir()) == []  # nothing written anywhere


@pytest.mark.parametrize("name", ["p", "Anna_B-2.v", "0", "x" * 64])
def test_good_patient_names_are_files_in_the_folder(tmp_path, name):
    assert learned_path(tmp_path, name) == tmp_path / f"{name}.json"


# -- bad files ---------------------------------------------------------------------------------

BAD_FILES = {
    "empty": b"",
    "not json": b"{theta: 1",
    "not utf-8": b"\xff\xfe\x00\x81",
    "a list": b"[1, 2]",
    "unknown format": json.dumps(valid_file(format="some other tool")).encode(),
    "no format": json.dumps({k: v for k, v in valid_file().items() if k != "format"}).encode(),
    "newer version": json.dumps(valid_file(version=learned.VERSION + 1)).encode(),
    "another X_CoM/X_SP": json.dumps(valid_file(x_ratio="both feet and stick tips")).encode(),
    "no X_CoM/X_SP": json.dumps({k: v for k, v in valid_file().items() if k != "x_ratio"}).encode(),
    "no theta": json.dumps({k: v for k, v in valid_file().items() if k != "theta"}).encode(),
    "one number": json.dumps(valid_file(theta=[1.0])).encode(),
    "three numbers": json.dumps(valid_file(theta=[-1.0, 0.5, 2.0])).encode(),
    "a string": json.dumps(valid_file(theta=["-1", 0.5])).encode(),
    "booleans": json.dumps(valid_file(theta=[False, True])).encode(),
    "NaN": json.dumps(valid_file(theta=[math.nan, 0.5])).encode(),
    "Infinity": json.dumps(valid_file(theta=[-1.0, math.inf])).encode(),
    "learner not an object": json.dumps(valid_file(learner=[1, 2])).encode(),
    "nested too deep": b"[" * 100_000,
}


@pytest.mark.parametrize("kind", list(BAD_FILES))
def test_a_bad_patient_file_is_a_one_line_error_naming_it(tmp_path, kind):
    path = tmp_path / "p.json"
    path.write_bytes(BAD_FILES[kind])
    with pytest.raises(LearnedError) as info:
        load_learned(tmp_path, "p")
    assert_one_line_naming(info.value, path)


@pytest.mark.parametrize("version", [1, 2])
def test_a_file_learned_on_an_older_ratio_is_refused_to_be_relearned(tmp_path, version):
    # version 1 files hold a theta of X_CoM/X_SP over both feet, version 2 over the stance ankle and
    # the tips: on this controller's ratio (from the stance heel) it would ask for other steps entirely
    path = tmp_path / "p.json"
    path.write_text(json.dumps({k: v for k, v in valid_file(version=version).items() if k != "x_ratio"}))
    with pytest.raises(LearnedError, match=f"version {version}.*relearn") as info:
        load_learned(tmp_path, "p")
    assert_one_line_naming(info.value, path)


def test_a_folder_in_place_of_the_file_is_an_error(tmp_path):
    (tmp_path / "p.json").mkdir()
    with pytest.raises(LearnedError) as info:
        load_learned(tmp_path, "p")
    assert_one_line_naming(info.value, tmp_path / "p.json")


def test_a_theta_outside_the_learning_bounds_is_an_error(tmp_path):
    c = BASE.controller.learning
    lower, upper = (c.alpha_min, c.xhat_min), (c.alpha_max, c.xhat_max)
    inside = [(c.alpha_min + c.alpha_max) / 2, (c.xhat_min + c.xhat_max) / 2]
    (tmp_path / "ok.json").write_text(json.dumps(valid_file(theta=inside)))
    assert load_learned(tmp_path, "ok", lower=lower, upper=upper).theta == tuple(inside)
    for theta in ([c.alpha_max + 1.0, inside[1]], [inside[0], c.xhat_min - 0.1], [c.alpha_min - 100.0, c.xhat_max + 1.0]):
        (tmp_path / "p.json").write_text(json.dumps(valid_file(theta=theta)))
        with pytest.raises(LearnedError, match="outside the bounds") as info:
            load_learned(tmp_path, "p", lower=lower, upper=upper)
        assert_one_line_naming(info.value, tmp_path / "p.json")


@pytest.mark.parametrize("corrupt", ["format", "theta outside its bounds", "eps of another theta", "unknown parameter", "not a dict"])
def test_a_corrupt_learner_state_is_an_error_naming_the_file(tmp_path, corrupt):
    state = learner_state(learner_with_an_update())
    if corrupt == "format":
        state["format"] = "something else"
    elif corrupt == "theta outside its bounds":
        state["theta"] = [state["params"]["upper"][0] + 5.0, state["theta"][1]]
    elif corrupt == "eps of another theta":
        state["batch"][0]["eps"] = [v + 0.5 for v in state["batch"][0]["eps"]]
    elif corrupt == "unknown parameter":
        state["params"]["not_a_parameter"] = 1
    else:
        state["params"] = [1, 2, 3]
    path = tmp_path / "p.json"
    path.write_text(json.dumps(valid_file(learner=state)))
    record = load_learned(tmp_path, "p")  # the file itself is well-formed ...
    with pytest.raises(LearnedError) as info:  # ... its learner is not
        restore_learner(record, np.random.default_rng(0), path)
    assert_one_line_naming(info.value, path)


def test_an_unwritable_place_is_an_error_naming_the_file(tmp_path):
    (tmp_path / "plain-file").write_text("")
    with pytest.raises(LearnedError) as info:
        save_learned(tmp_path / "plain-file", "p", (0.0, 0.5), None)
    assert_one_line_naming(info.value, tmp_path / "plain-file" / "p.json")


# -- the saver ---------------------------------------------------------------------------------


def test_the_saver_writes_off_the_tick_and_a_newer_state_replaces_one_not_yet_written(tmp_path, monkeypatch):
    real_write = learned._write
    entered, release = threading.Event(), threading.Event()
    writers: list[int] = []

    def slow_write(*args):
        writers.append(threading.get_ident())
        entered.set()
        assert release.wait(30)  # the disk hangs
        return real_write(*args)

    monkeypatch.setattr(learned, "_write", slow_write)
    saver = LearnedSaver(tmp_path, "p")
    try:
        saver.submit((-1.0, 0.5), None)
        assert entered.wait(30)  # the writer thread is in the first write, and hangs there ...
        saver.submit((-2.0, 0.6), None)  # ... while the tick goes on: submit never waits for the disk
        saver.submit((-3.0, 0.7), None)
        assert not (tmp_path / "p.json").exists() and saver.writes == 0
    finally:
        release.set()
        saver.close()
    assert threading.get_ident() not in writers  # every write on the saver's thread
    assert saver.writes == 2 and saver.errors == []  # the first, then only the newest of the two waiting
    assert load_learned(tmp_path, "p").theta == (-3.0, 0.7)


def test_close_writes_what_is_pending(tmp_path, monkeypatch):
    real_write = learned._write
    release = threading.Event()

    def slow_write(*args):
        assert release.wait(30)
        return real_write(*args)

    monkeypatch.setattr(learned, "_write", slow_write)
    pi2 = learner_with_an_update()
    saver = LearnedSaver(tmp_path, "p")
    saver.submit(pi2.evaluation_theta(), pi2)
    timer = threading.Timer(0.2, release.set)  # the write completes only after close() was called
    timer.start()
    try:
        saver.close()
    finally:
        timer.cancel()
        release.set()
    assert saver.writes == 1
    record = load_learned(tmp_path, "p")
    assert record.theta == tuple(float(v) for v in pi2.evaluation_theta())
    assert record.learner_state == as_json(learner_state(pi2))


def test_the_saver_snapshots_the_learner_when_submitted(tmp_path, monkeypatch):
    real_write = learned._write
    release = threading.Event()
    monkeypatch.setattr(learned, "_write", lambda *a: (release.wait(30), real_write(*a)))
    pi2 = learner_with_an_update()
    before = learner_state(pi2)
    saver = LearnedSaver(tmp_path, "p")
    saver.submit(pi2.evaluation_theta(), pi2)
    pi2.ask()  # the learner goes on learning before the write happened
    pi2.tell_step(50.0)
    pi2.tell_step(51.0)
    pi2.end_rollout(False)  # a second update
    assert pi2.n_updates == 2
    release.set()
    saver.close()
    assert load_learned(tmp_path, "p").learner_state == as_json(before)


def test_a_write_error_is_kept_not_raised_into_the_tick(tmp_path):
    (tmp_path / "plain-file").write_text("")
    saver = LearnedSaver(tmp_path / "plain-file", "p")
    saver.submit((0.0, 0.5), None)  # no exception here ...
    saver.close()  # ... nor here
    assert saver.writes == 0 and len(saver.errors) == 1
    assert str(tmp_path / "plain-file" / "p.json") in saver.errors[0]


def test_a_saver_for_a_bad_name_fails_at_once(tmp_path):
    with pytest.raises(LearnedError):
        LearnedSaver(tmp_path, "../p")
