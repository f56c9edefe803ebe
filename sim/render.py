"""Headless offscreen rendering for the README: single frames, a PNG strip of snapshots, an animated GIF.

Everything goes through ``getCameraImage(..., renderer=ER_TINY_RENDERER)`` of the client passed in
(a :class:`pybullet_utils.bullet_client.BulletClient` on a DIRECT connection, or any object with the
same methods): Bullet's software rasteriser, so no window, GUI or OpenGL context is needed.

The camera matrices are computed here in numpy (the same formulas as Bullet's
``computeViewMatrixFromYawPitchRoll`` and ``computeProjectionMatrixFOV``), so this module does not
import pybullet at all. Pillow is imported only when a file is written: it is required for GIFs and
for strip captions; without it :meth:`Recorder.save_strip` still writes an uncaptioned PNG.
"""

from __future__ import annotations

import math
import numbers
import os
import struct
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import IO, Any, NamedTuple

import numpy as np

from config.files import atomic_write

ER_TINY_RENDERER = 1 << 16  # pybullet.ER_TINY_RENDERER (tests check the value)
ER_NO_SEGMENTATION_MASK = 4  # pybullet.ER_NO_SEGMENTATION_MASK: skip work we would throw away

DEFAULT_CAPTION = "t = {t:.1f} s"


@dataclass(frozen=True)
class Camera:
    """A camera orbiting ``target_xyz`` (z up), as in pybullet's yaw/pitch debug camera.

    ``yaw_deg`` = 0 puts the eye on the -y side of the target looking towards +y (a side view of a
    robot walking along +x); ``pitch_deg`` < 0 looks down from above.
    """

    target_xyz: tuple[float, float, float] = (0.0, 0.0, 0.9)
    distance_m: float = 3.0
    yaw_deg: float = 0.0
    pitch_deg: float = -10.0
    width_px: int = 320
    height_px: int = 240
    fov_deg: float = 50.0
    near_m: float = 0.05
    far_m: float = 30.0

    def __post_init__(self) -> None:
        if len(self.target_xyz) != 3:
            raise ValueError(f"target_xyz needs 3 coordinates, got {self.target_xyz!r}")
        object.__setattr__(self, "target_xyz", tuple(float(v) for v in self.target_xyz))
        if not (isinstance(self.width_px, numbers.Integral) and isinstance(self.height_px, numbers.Integral)):
            raise TypeError("width_px and height_px must be ints")
        if self.width_px <= 0 or self.height_px <= 0:
            raise ValueError(f"image size must be positive, got {self.width_px}x{self.height_px}")
        if not self.distance_m > 0:
            raise ValueError(f"distance_m must be > 0, got {self.distance_m}")
        if not 0 < self.fov_deg < 180:
            raise ValueError(f"fov_deg must be in (0, 180), got {self.fov_deg}")
        if not 0 < self.near_m < self.far_m:
            raise ValueError(f"need 0 < near_m < far_m, got {self.near_m}, {self.far_m}")

    def follow(self, x: float) -> Camera:
        """A copy whose target has x = ``x`` (y and z kept): call it each frame with the robot's x."""
        _, y, z = self.target_xyz
        return replace(self, target_xyz=(float(x), y, z))

    @property
    def aspect(self) -> float:
        return self.width_px / self.height_px


# ---------------------------------------------------------------------------------------------
# Pure helpers


def eye_position(camera: Camera) -> np.ndarray:
    """Where the camera sits (Bullet's yaw/pitch convention, z up, roll 0)."""
    yaw, pitch = math.radians(camera.yaw_deg), math.radians(camera.pitch_deg)
    d = camera.distance_m
    offset = np.array([d * math.cos(pitch) * math.sin(yaw), -d * math.cos(pitch) * math.cos(yaw), -d * math.sin(pitch)])
    return np.asarray(camera.target_xyz) + offset


def view_matrix(camera: Camera) -> list[float]:
    """The 16 floats of the OpenGL view matrix (column-major), as ``computeViewMatrixFromYawPitchRoll``."""
    yaw, pitch = math.radians(camera.yaw_deg), math.radians(camera.pitch_deg)
    eye = eye_position(camera)
    target = np.asarray(camera.target_xyz)
    up = np.array([math.sin(pitch) * math.sin(yaw), -math.sin(pitch) * math.cos(yaw), math.cos(pitch)])
    f = target - eye
    f /= np.linalg.norm(f)
    s = np.cross(f, up)
    s /= np.linalg.norm(s)
    u = np.cross(s, f)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = s, u, -f
    m[:3, 3] = -m[:3, :3] @ eye
    return [float(v) for v in m.T.ravel()]


def projection_matrix(camera: Camera) -> list[float]:
    """The 16 floats of the OpenGL projection matrix (column-major), as ``computeProjectionMatrixFOV``."""
    y_scale = 1.0 / math.tan(math.radians(camera.fov_deg) / 2.0)
    near, far = camera.near_m, camera.far_m
    m = [0.0] * 16
    m[0] = y_scale / camera.aspect
    m[5] = y_scale
    m[10] = (far + near) / (near - far)
    m[11] = -1.0
    m[14] = 2.0 * far * near / (near - far)
    return m


def rgb_from_camera_image(width: int, height: int, rgba: Any) -> np.ndarray:
    """The (H, W, 3) uint8 image from ``getCameraImage``'s pixels: an (H, W, 4) array or a flat sequence."""
    pixels = np.asarray(rgba, dtype=np.uint8)
    if pixels.size != width * height * 4:
        raise ValueError(f"expected {width}x{height} RGBA pixels, got {pixels.size} values")
    return np.ascontiguousarray(pixels.reshape(height, width, 4)[:, :, :3])


def pick_evenly(n_items: int, k: int) -> list[int]:
    """``min(k, n_items)`` distinct indices spread evenly over ``range(n_items)``, first and last included."""
    if n_items <= 0 or k <= 0:
        return []
    if k == 1:
        return [n_items - 1]
    return sorted({int(i) for i in np.linspace(0, n_items - 1, min(k, n_items)).round()})


def hstack_with_separator(images: Sequence[np.ndarray], separator_px: int = 2, separator_rgb=(255, 255, 255)) -> np.ndarray:
    """Images of equal height side by side, with vertical bars ``separator_px`` wide between them."""
    if not images:
        raise ValueError("no images to stack")
    height = images[0].shape[0]
    if any(img.shape[0] != height for img in images):
        raise ValueError("all images of a strip need the same height")
    bar = np.empty((height, separator_px, 3), dtype=np.uint8)
    bar[:] = np.asarray(separator_rgb, dtype=np.uint8)
    parts: list[np.ndarray] = []
    for i, img in enumerate(images):
        if i and separator_px > 0:
            parts.append(bar)
        parts.append(img)
    return np.concatenate(parts, axis=1)


def encode_png(rgb: np.ndarray) -> bytes:
    """A minimal RGB PNG (stdlib only) for when Pillow is missing."""
    height, width, _ = rgb.shape
    rows = np.concatenate([np.zeros((height, 1), dtype=np.uint8), rgb.reshape(height, width * 3)], axis=1)

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)  # 8-bit truecolour
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(rows.tobytes(), 9)) + chunk(b"IEND", b"")


# ---------------------------------------------------------------------------------------------
# Rendering


def render_frame(client: Any, camera: Camera, *, shadow: bool = False) -> np.ndarray:
    """One (H, W, 3) uint8 RGB image of ``client``'s world, rendered by the tiny (software) renderer."""
    width, height, rgba, _depth, _seg = client.getCameraImage(
        camera.width_px,
        camera.height_px,
        viewMatrix=view_matrix(camera),
        projectionMatrix=projection_matrix(camera),
        shadow=int(shadow),
        flags=ER_NO_SEGMENTATION_MASK,
        renderer=ER_TINY_RENDERER,
    )
    return rgb_from_camera_image(width, height, rgba)


class Frame(NamedTuple):
    t: float  # simulation time, s
    image: np.ndarray  # (H, W, 3) uint8


@dataclass
class Recorder:
    """Keeps every ``every_n``-th frame offered to :meth:`maybe_capture`, at most ``max_frames`` of them.

    When full it drops every other frame and doubles its stride, so memory stays bounded while the
    frames still cover the whole run evenly (320x240 RGB is 230 kB a frame).
    """

    every_n: int = 1
    max_frames: int = 256
    shadow: bool = False
    _frames: list[Frame] = field(default_factory=list, init=False, repr=False)
    _calls: int = field(default=0, init=False, repr=False)
    _stride: int = field(default=0, init=False, repr=False)

    def __post_init__(self) -> None:
        if self.every_n < 1:
            raise ValueError(f"every_n must be >= 1, got {self.every_n}")
        if self.max_frames < 2:
            raise ValueError(f"max_frames must be >= 2, got {self.max_frames}")
        self._stride = self.every_n

    @property
    def frames(self) -> tuple[Frame, ...]:
        return tuple(self._frames)

    @property
    def stride(self) -> int:
        """Calls of :meth:`maybe_capture` per kept frame (``every_n``, doubled each time memory ran out)."""
        return self._stride

    def __len__(self) -> int:
        return len(self._frames)

    def maybe_capture(self, client: Any, t: float, camera: Camera) -> bool:
        """Render and keep a frame if this call is due (the first call always is); True if it was."""
        due = self._calls % self._stride == 0
        self._calls += 1
        if due:
            self.add(t, render_frame(client, camera, shadow=self.shadow))
        return due

    def add(self, t: float, image: np.ndarray) -> None:
        """Keep an already rendered frame (same size as the others)."""
        if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
            raise ValueError(f"expected an (H, W, 3) uint8 image, got {image.shape} {image.dtype}")
        if self._frames and image.shape != self._frames[0].image.shape:
            raise ValueError(f"frame size changed from {self._frames[0].image.shape} to {image.shape}")
        self._frames.append(Frame(float(t), image))
        if len(self._frames) > self.max_frames:
            self._frames = self._frames[::2]
            self._stride *= 2

    def save_gif(self, path: str | os.PathLike[str], fps: float | None = None, colors: int = 64) -> Path:
        """Write an endlessly looping GIF; ``fps`` None plays at simulation speed (capped at 50 fps).

        One palette (``colors`` entries, from a sample of frames) serves every frame, without
        dithering, so Pillow can store only the changed part of each frame: small files.
        """
        from PIL import Image

        frames = self._require_frames()
        if fps is None:
            span = frames[-1].t - frames[0].t
            fps = (len(frames) - 1) / span if len(frames) > 1 and span > 0 else 10.0
        if not fps > 0:
            raise ValueError(f"fps must be > 0, got {fps}")
        duration_ms = max(20, round(1000.0 / fps))  # browsers slow down GIF frames shorter than 20 ms

        sample = np.concatenate([frames[i].image for i in pick_evenly(len(frames), 8)], axis=0)
        palette = Image.fromarray(sample).quantize(colors=colors, method=Image.Quantize.MEDIANCUT)
        images = [Image.fromarray(f.image).quantize(palette=palette, dither=Image.Dither.NONE) for f in frames]

        def write(f: IO[bytes]) -> None:
            images[0].save(f, format="GIF", save_all=True, append_images=images[1:], duration=duration_ms, loop=0, optimize=False)

        return atomic_write(path, write)

    def save_strip(
        self,
        path: str | os.PathLike[str],
        n_panels: int = 6,
        *,
        caption: str | None = DEFAULT_CAPTION,
        separator_px: int = 2,
        separator_rgb: tuple[int, int, int] = (255, 255, 255),
    ) -> Path:
        """Write a PNG of ``n_panels`` frames chosen evenly over the recording, side by side.

        ``caption`` is formatted with ``t`` (the frame's time) and drawn in each panel's top-left
        corner with Pillow's default font; without Pillow the PNG is written uncaptioned.
        """
        if n_panels < 1:
            raise ValueError(f"n_panels must be >= 1, got {n_panels}")
        frames = self._require_frames()
        chosen = [frames[i] for i in pick_evenly(len(frames), n_panels)]
        try:
            from PIL import Image, ImageDraw, ImageFont
        except ImportError:
            strip = hstack_with_separator([f.image for f in chosen], separator_px, separator_rgb)
            png = encode_png(strip)
            return atomic_write(path, lambda f: f.write(png))

        panels = []
        for frame in chosen:
            image = frame.image
            if caption is not None:
                panel = Image.fromarray(image)
                draw = ImageDraw.Draw(panel)
                draw.text((4, 3), caption.format(t=frame.t), fill=(0, 0, 0), font=ImageFont.load_default(), stroke_width=1, stroke_fill=(255, 255, 255))
                image = np.asarray(panel)
            panels.append(image)
        strip = Image.fromarray(hstack_with_separator(panels, separator_px, separator_rgb))
        return atomic_write(path, lambda f: strip.save(f, format="PNG", optimize=True))

    def _require_frames(self) -> list[Frame]:
        if not self._frames:
            raise ValueError("nothing recorded yet")
        return self._frames
