"""sim.render: headless tiny-renderer frames, the bounded Recorder, GIF and PNG strip files."""

from __future__ import annotations

import sys
from dataclasses import FrozenInstanceError

import numpy as np
import pybullet
import pybullet_data
import pytest
from PIL import Image
from pybullet_utils.bullet_client import BulletClient

from config.files import atomic_write
from sim.render import (
    ER_NO_SEGMENTATION_MASK,
    ER_TINY_RENDERER,
    Camera,
    Recorder,
    encode_png,
    hstack_with_separator,
    pick_evenly,
    projection_matrix,
    render_frame,
    rgb_from_camera_image,
    view_matrix,
)

CAMERA = Camera(target_xyz=(0.3, 0.0, 0.6), distance_m=2.5, yaw_deg=0.0, pitch_deg=-15.0, width_px=320, height_px=240)
DT = 1.0 / 240.0


@pytest.fixture
def client():
    c = BulletClient(pybullet.DIRECT)
    c.setAdditionalSearchPath(pybullet_data.getDataPath())
    c.setGravity(0, 0, -9.81)
    c.setTimeStep(DT)
    c.loadURDF("plane.urdf")
    yield c
    c.disconnect()


def add_box(c) -> int:
    """A red box thrown sideways and up, in the middle of CAMERA's view."""
    half = [0.15, 0.15, 0.15]
    col = c.createCollisionShape(c.GEOM_BOX, halfExtents=half)
    vis = c.createVisualShape(c.GEOM_BOX, halfExtents=half, rgbaColor=[0.9, 0.15, 0.1, 1.0])
    box = c.createMultiBody(baseMass=1.0, baseCollisionShapeIndex=col, baseVisualShapeIndex=vis, basePosition=[0, 0, 0.8])
    c.resetBaseVelocity(box, linearVelocity=[1.5, 0, 2.0], angularVelocity=[0, 3.0, 0])
    return box


def record_throw(c, recorder: Recorder, steps: int = 96) -> None:
    for i in range(steps):
        recorder.maybe_capture(c, i * DT, CAMERA)
        c.stepSimulation()


def test_constants_are_pybullets():
    assert ER_TINY_RENDERER == pybullet.ER_TINY_RENDERER
    assert ER_NO_SEGMENTATION_MASK == pybullet.ER_NO_SEGMENTATION_MASK


@pytest.mark.parametrize(
    "camera",
    [CAMERA, Camera(), Camera((1.0, 2.0, 3.0), 2.0, 30.0, -20.0), Camera((0, 0, 0), 5.0, -135.0, 40.0, 640, 200, fov_deg=70.0)],
)
def test_matrices_match_bullets(client, camera):
    expected_view = client.computeViewMatrixFromYawPitchRoll(camera.target_xyz, camera.distance_m, camera.yaw_deg, camera.pitch_deg, 0, 2)
    expected_proj = client.computeProjectionMatrixFOV(camera.fov_deg, camera.aspect, camera.near_m, camera.far_m)
    np.testing.assert_allclose(view_matrix(camera), expected_view, atol=1e-5)
    np.testing.assert_allclose(projection_matrix(camera), expected_proj, atol=1e-5)


def test_camera_follow_is_a_copy():
    moved = CAMERA.follow(4.25)
    assert moved.target_xyz == (4.25, 0.0, 0.6)
    assert CAMERA.target_xyz == (0.3, 0.0, 0.6)
    assert moved.distance_m == CAMERA.distance_m and moved.width_px == CAMERA.width_px
    with pytest.raises(FrozenInstanceError):
        CAMERA.distance_m = 1.0  # type: ignore[misc]


@pytest.mark.parametrize(
    "kwargs", [{"width_px": 0}, {"height_px": -1}, {"distance_m": 0.0}, {"fov_deg": 180.0}, {"near_m": 5.0, "far_m": 1.0}]
)
def test_camera_rejects_nonsense(kwargs):
    with pytest.raises(ValueError):
        Camera(**kwargs)


def test_rgb_from_flat_list_and_from_array_agree():
    rgba = np.arange(3 * 2 * 4, dtype=np.uint8).reshape(2, 3, 4)
    from_array = rgb_from_camera_image(3, 2, rgba)
    from_list = rgb_from_camera_image(3, 2, rgba.ravel().tolist())
    assert from_array.shape == (2, 3, 3) and from_array.dtype == np.uint8
    np.testing.assert_array_equal(from_array, rgba[:, :, :3])
    np.testing.assert_array_equal(from_list, from_array)
    with pytest.raises(ValueError):
        rgb_from_camera_image(3, 3, rgba)


def test_render_frame_shows_the_box_and_its_motion(client):
    empty = render_frame(client, CAMERA)
    assert empty.shape == (240, 320, 3) and empty.dtype == np.uint8

    add_box(client)
    first = render_frame(client, CAMERA)
    assert first.shape == (240, 320, 3) and first.dtype == np.uint8
    assert first.reshape(-1, 3).std(axis=0).max() > 5, "image is uniform"
    changed = np.any(first != empty, axis=2)
    assert changed.sum() > 500, "the box is not visible"
    red = (first[:, :, 0] > 120) & (first[:, :, 1] < 80) & (first[:, :, 2] < 80)
    assert red.sum() > 200, "no red box pixels"

    for _ in range(30):
        client.stepSimulation()
    later = render_frame(client, CAMERA)
    assert np.any(later != first, axis=2).sum() > 200, "frames at different times are identical"


def test_render_frame_accepts_a_flat_pixel_list():
    class FlatClient:
        """Like pybullet built without numpy: pixels come back as one flat sequence."""

        def __init__(self):
            self.kwargs = None

        def getCameraImage(self, width, height, **kwargs):
            self.kwargs = kwargs
            return width, height, [7, 8, 9, 255] * (width * height), None, None

    fake = FlatClient()
    image = render_frame(fake, Camera(width_px=4, height_px=3))
    assert image.shape == (3, 4, 3) and image.dtype == np.uint8
    assert (image == [7, 8, 9]).all()
    assert fake.kwargs["renderer"] == pybullet.ER_TINY_RENDERER


def test_recorder_saves_gif_and_strip(client, tmp_path):
    add_box(client)
    recorder = Recorder(every_n=4)
    record_throw(client, recorder, steps=96)
    frames = recorder.frames
    assert len(frames) == 24
    assert [f.t for f in frames] == pytest.approx([i * 4 * DT for i in range(24)])
    assert all(np.any(a.image != b.image) for a, b in zip(frames, frames[1:])), "some frames repeat"

    gif = recorder.save_gif(tmp_path / "throw.gif", fps=12)
    strip = recorder.save_strip(tmp_path / "throw.png", n_panels=5, separator_px=3)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["throw.gif", "throw.png"], "a .tmp file was left behind"

    with Image.open(gif) as im:
        assert im.format == "GIF"
        assert im.size == (320, 240)
        assert im.n_frames == 24
        assert im.info["loop"] == 0
        assert im.info["duration"] == pytest.approx(1000 / 12, abs=10)
    assert gif.stat().st_size < 24 * 20_000

    with Image.open(strip) as im:
        assert im.format == "PNG"
        assert im.size == (5 * 320 + 4 * 3, 240)
        pixels = np.asarray(im.convert("RGB"))
    assert (pixels[:, 320:323] == 255).all(), "no separator between the panels"
    # The caption sits in the top-left corner of each panel; the plain frame has no black text there.
    assert (pixels[:20, :80].min(axis=2) < 40).any()
    assert not (frames[0].image[:20, :80].min(axis=2) < 40).any()


def test_gif_at_simulation_speed_by_default(tmp_path):
    recorder = Recorder()
    for i in range(5):
        recorder.add(i * 0.1, np.full((6, 8, 3), 40 * i, dtype=np.uint8))
    with Image.open(recorder.save_gif(tmp_path / "a.gif")) as im:
        assert im.n_frames == 5
        assert im.info["duration"] == 100


def test_strip_without_pillow_is_still_a_png(tmp_path, monkeypatch):
    recorder = Recorder()
    for i in range(4):
        recorder.add(float(i), np.full((10, 12, 3), 60 * i, dtype=np.uint8))
    with monkeypatch.context() as m:
        m.setitem(sys.modules, "PIL", None)  # `from PIL import ...` now raises ImportError
        path = recorder.save_strip(tmp_path / "plain.png", n_panels=3, separator_px=1, separator_rgb=(1, 2, 3))
    with Image.open(path) as im:
        assert im.size == (3 * 12 + 2, 10)
        pixels = np.asarray(im.convert("RGB"))
    np.testing.assert_array_equal(pixels[:, :12], 0)  # panels: frames 0, 2 (rounded from 1.5) and 3
    np.testing.assert_array_equal(pixels[:, 12], [[1, 2, 3]] * 10)
    np.testing.assert_array_equal(pixels[:, 13:25], 120)
    np.testing.assert_array_equal(pixels[:, 26:], 180)


def test_recorder_memory_is_bounded_and_stays_even():
    class FlatClient:
        def getCameraImage(self, width, height, **kwargs):
            return width, height, [0, 0, 0, 255] * (width * height), None, None

    camera = Camera(width_px=4, height_px=3)
    recorder = Recorder(every_n=3, max_frames=10)
    captured = [recorder.maybe_capture(FlatClient(), float(i), camera) for i in range(300)]
    assert captured[0] and not captured[1]
    assert 5 <= len(recorder) <= 10
    times = [f.t for f in recorder.frames]
    assert times[0] == 0.0 and times[-1] > 250
    assert len(set(np.diff(times))) == 1, f"frames not evenly spaced: {times}"
    assert np.diff(times)[0] == recorder.stride


def test_recorder_rejects_bad_frames_and_empty_saves(tmp_path):
    recorder = Recorder()
    with pytest.raises(ValueError):
        recorder.save_gif(tmp_path / "x.gif")
    with pytest.raises(ValueError):
        recorder.save_strip(tmp_path / "x.png")
    recorder.add(0.0, np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(ValueError):
        recorder.add(1.0, np.zeros((4, 5, 3), np.uint8))
    with pytest.raises(ValueError):
        recorder.add(1.0, np.zeros((4, 4, 3), np.float32))
    assert list(tmp_path.iterdir()) == []


def test_atomic_write_keeps_the_old_file_on_error(tmp_path):
    target = tmp_path / "out.png"
    target.write_bytes(b"old")

    def crash(f):
        f.write(b"half a fi")
        raise RuntimeError("crash")

    with pytest.raises(RuntimeError):
        atomic_write(target, crash)
    assert target.read_bytes() == b"old"
    assert list(tmp_path.iterdir()) == [target]

    atomic_write(target, lambda f: f.write(b"new"))
    assert target.read_bytes() == b"new"
    assert list(tmp_path.iterdir()) == [target]


def test_pure_helpers():
    assert pick_evenly(10, 3) == [0, 4, 9]  # 4.5 rounds half to even
    assert pick_evenly(3, 10) == [0, 1, 2]
    assert pick_evenly(5, 1) == [4]
    assert pick_evenly(0, 3) == []
    a, b = np.zeros((2, 2, 3), np.uint8), np.full((2, 3, 3), 9, np.uint8)
    stacked = hstack_with_separator([a, b], separator_px=1, separator_rgb=(5, 5, 5))
    assert stacked.shape == (2, 6, 3)
    assert (stacked[:, 2] == 5).all()
    png = encode_png(stacked)
    assert png.startswith(b"\x89PNG\r\n\x1a\n")
