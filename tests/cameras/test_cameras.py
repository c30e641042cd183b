"""Tests of dyndlo_vision.cameras: MuJoCo off-screen camera, video files, image folders, devices."""

from __future__ import annotations

import importlib.util
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest

from dyndlo_vision.cameras._base import average_frames
from dyndlo_vision.cameras.devices import OpenCVDeviceCamera, RealSenseCamera
from dyndlo_vision.cameras.files import TruncatedVideoError, VideoFileCamera
from dyndlo_vision.cameras.protocol import Camera, Frame
from dyndlo_vision.cameras.simulated import DelayedCamera, MujocoCamera
from dyndlo_vision.sim.scene import BoxProp, Scene, SceneConfig
from dyndlo_vision.tracking.tracker import lift_with_depth

# ----------------------------------------------------------------------------------------------- latency


class ClockCamera:
    """Frames captured every ``period`` s (t = index * period), ``frames`` of them, then None."""

    def __init__(self, period: float = 0.04, frames: int = 100) -> None:
        self.period, self.frames, self.index, self.closed = period, frames, 0, False

    def read(self) -> Frame | None:
        if self.index >= self.frames:
            return None
        frame = Frame(np.full((2, 2, 3), self.index, np.uint8), self.index * self.period, self.index)
        self.index += 1
        return frame

    def close(self) -> None:
        self.closed = True


@pytest.mark.parametrize(
    ("latency_s", "delay_periods"), [(0.0, 0), (0.04, 1), (0.08, 2), (0.05, 2), (0.12, 3)]
)
def test_delayed_camera_hands_each_frame_over_once_after_the_latency(
    latency_s: float, delay_periods: int
) -> None:
    cam = DelayedCamera(ClockCamera(), latency_s)
    assert isinstance(cam, Camera)
    got = [cam.read() for _ in range(12)]
    assert got[0] is not None and got[0].index == 0  # the first frame at once: the loop starts with one
    # Frames 1, 2, ... arrive delay_periods reads after their capture; the reads in between get nothing yet.
    assert all(f is None for f in got[1 : 1 + delay_periods])
    delivered = got[1 + delay_periods :]
    assert [f.index for f in delivered] == list(range(1, 12 - delay_periods))
    # Capture times are the frames' own (a filter can predict across the delay).
    for read, frame in enumerate(got[1 + delay_periods :], start=1 + delay_periods):
        assert frame.t_capture == pytest.approx((read - delay_periods) * 0.04)


def test_delayed_camera_at_the_end_of_its_source_and_on_bad_input() -> None:
    source = ClockCamera(frames=4)
    cam = DelayedCamera(source, 0.08)
    got = [cam.read() for _ in range(6)]
    # read 0: frame 0; reads 1-2: not yet; read 3: frame 1; read 4: the source is out, the newest left (3).
    assert [None if f is None else f.index for f in got] == [0, None, None, 1, 3, None]
    with pytest.raises(TypeError, match="iterate over the wrapped camera"):
        iter(cam)
    cam.close()
    assert source.closed
    for bad in (-0.01, float("nan"), float("inf"), "40ms", True):
        with pytest.raises(ValueError, match="latency_s must be a finite number >= 0"):
            DelayedCamera(ClockCamera(), bad)  # type: ignore[arg-type]


# ------------------------------------------------------------------------------------------------ MuJoCo

#: A box in front of the "front" camera (at y = -1.7 looking along +y): its front face is at y = -0.05.
_BOX = BoxProp("probe", center_m=(0.9, 0.0, 0.3), size_m=(0.1, 0.1, 0.1))
_FRONT_CAMERA_Y = -1.7


@pytest.fixture(scope="module")
def scene() -> Scene:
    return Scene(SceneConfig(boxes=(_BOX,), image_size=(320, 240), settle_s=0.1))


@pytest.fixture
def camera(scene: Scene):
    scene.reset()
    # No skip when rendering fails: the package needs off-screen rendering (CI installs OSMesa/EGL).
    cam = MujocoCamera(scene.model, scene.data, "front", width=320, height=240, depth=True)
    yield cam
    cam.close()


def test_mujoco_frame_shape_time_and_index(scene: Scene, camera: MujocoCamera) -> None:
    assert isinstance(camera, Camera)
    first = camera.read()
    assert first.rgb.shape == (240, 320, 3) and first.rgb.dtype == np.uint8
    assert first.depth is not None and first.depth.shape == (240, 320) and first.depth.dtype == np.float32
    assert first.t_capture == 0.0 and first.index == 0
    scene.step(37)
    second = camera.read()
    assert second.t_capture == pytest.approx(37 * scene.timestep, abs=1e-12)
    assert second.t_capture == scene.data.time
    assert second.index == 1


def test_mujoco_depth_matches_known_geometry(camera: MujocoCamera) -> None:
    frame = camera.read()
    cal = camera.calibration
    assert frame.depth is not None
    # The box's front face, 1.65 m in front of the camera along its optical axis.
    face_centre = np.array([_BOX.center_m[0], _BOX.center_m[1] - _BOX.size_m[1] / 2, _BOX.center_m[2]])
    u, v = np.rint(cal.project(face_centre)[0]).astype(int)
    assert frame.depth[v, u] == pytest.approx(face_centre[1] - _FRONT_CAMERA_Y, abs=2e-3)
    # Every pixel of the bottom rows sees the floor: lifted with depth and calibration, it lies at z = 0.
    rows, cols = np.mgrid[200:240:7, 0:320:13]
    uv = np.column_stack((cols.ravel(), rows.ravel())).astype(float)
    floor = lift_with_depth(uv, frame.depth, cal, window=0)
    assert np.all(np.isfinite(floor))
    np.testing.assert_allclose(floor[:, 2], 0.0, atol=2e-3)
    # The top row looks above the horizon at nothing: NaN, not the far clipping plane.
    assert np.all(np.isnan(frame.depth[0]))


def test_mujoco_rgb_only_and_close(scene: Scene) -> None:
    cam = MujocoCamera(scene.model, scene.data, "oblique", width=160, height=120)
    with cam:
        frame = cam.read()
        assert frame.depth is None and frame.rgb.shape == (120, 160, 3)
    cam.close()  # twice is fine
    with pytest.raises(ValueError, match="closed"):
        cam.read()


def test_mujoco_camera_bad_arguments(scene: Scene) -> None:
    with pytest.raises(ValueError, match="'nope' is not in the model.*front"):
        MujocoCamera(scene.model, scene.data, "nope")
    with pytest.raises(ValueError, match="exceeds the model's off-screen framebuffer 320x240"):
        MujocoCamera(scene.model, scene.data, "front", width=640, height=480)
    with pytest.raises(ValueError, match="width must be a positive int"):
        MujocoCamera(scene.model, scene.data, "front", width=0, height=10)


def test_average_frames_is_the_rounded_mean() -> None:
    a = np.zeros((2, 3, 3), np.uint8)
    b = np.full((2, 3, 3), 255, np.uint8)
    c = np.full((2, 3, 3), 10, np.uint8)
    out = average_frames([a, b, c])
    assert out.dtype == np.uint8
    assert np.all(out == 88)  # (0 + 255 + 10) / 3 = 88.33
    np.testing.assert_array_equal(average_frames([c]), c)
    with pytest.raises(ValueError, match="at least one frame"):
        average_frames([])
    with pytest.raises(ValueError, match=r"frame 1 has shape \(2, 2, 3\)"):
        average_frames([a, a[:, :2]])
    with pytest.raises(ValueError, match="frame 0 has dtype float64"):
        average_frames([a.astype(float)])


# ------------------------------------------------------------------------------------------------ files

_COLORS_RGB = [(255, 0, 0), (0, 255, 0), (0, 0, 255), (255, 255, 0), (0, 255, 255), (255, 0, 255)]


def _frame(k: int, size: tuple[int, int] = (64, 48)) -> np.ndarray:
    """RGB frame k: a flat colour that identifies it."""
    img = np.empty((size[1], size[0], 3), np.uint8)
    img[:] = _COLORS_RGB[k % len(_COLORS_RGB)]
    return img


def _write_video(path: Path, n: int, fps: float, fourcc: str) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, (64, 48))
    assert writer.isOpened()
    for k in range(n):
        writer.write(cv2.cvtColor(_frame(k), cv2.COLOR_RGB2BGR))
    writer.release()
    return path


def _assert_is_frame_k(rgb: np.ndarray, k: int) -> None:
    """Colour of the frame's centre matches frame k (lossy codecs allow a little error)."""
    centre = rgb[24, 32].astype(int)
    np.testing.assert_allclose(centre, _COLORS_RGB[k % len(_COLORS_RGB)], atol=40)


def test_video_round_trip_rgb_and_time_stamps(tmp_path: Path) -> None:
    path = _write_video(tmp_path / "clip.mp4", 12, 10.0, "mp4v")
    with VideoFileCamera(path) as cam:
        assert isinstance(cam, Camera)
        assert (cam.width, cam.height, cam.frame_count, cam.fps, cam.fps_source) == (
            64,
            48,
            12,
            10.0,
            "header",
        )
        frames = list(cam)
        assert cam.read() is None  # stays at the end
    assert [f.index for f in frames] == list(range(12))
    for k, f in enumerate(frames):
        assert f.rgb.shape == (48, 64, 3) and f.rgb.dtype == np.uint8 and f.depth is None
        _assert_is_frame_k(f.rgb, k)  # RGB, not BGR
        assert f.t_capture == pytest.approx(k / 10.0, abs=1e-3)


def test_video_fps_argument_overrides_time_stamps(tmp_path: Path) -> None:
    path = _write_video(tmp_path / "clip.mp4", 5, 10.0, "mp4v")
    with VideoFileCamera(path, fps=50.0) as cam:
        assert cam.fps_source == "argument"
        assert [f.t_capture for f in cam] == pytest.approx([0.0, 0.02, 0.04, 0.06, 0.08])


def test_image_folder_natural_order_and_default_fps(tmp_path: Path) -> None:
    for k, name in enumerate(["f1.png", "f2.png", "f10.png"]):  # plain sorting would put f10 second
        cv2.imwrite(str(tmp_path / name), cv2.cvtColor(_frame(k), cv2.COLOR_RGB2BGR))
    (tmp_path / "notes.txt").write_text("not a frame")
    with pytest.warns(UserWarning, match="assuming 25 fps"):
        cam = VideoFileCamera(tmp_path)
    with cam:
        assert cam.fps_source == "default" and cam.frame_count == 3
        frames = list(cam)
    assert len(frames) == 3
    for k, f in enumerate(frames):
        np.testing.assert_array_equal(f.rgb, _frame(k))  # PNG is lossless: exact, in RGB order
        assert f.t_capture == pytest.approx(k / 25.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with VideoFileCamera(tmp_path, fps=5.0) as cam:
            assert [f.t_capture for f in cam] == pytest.approx([0.0, 0.2, 0.4])


def test_image_folder_errors(tmp_path: Path) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "readme.md").write_text("no images here")
    with pytest.raises(ValueError, match="contains no images"):
        VideoFileCamera(empty, fps=25)
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    cv2.imwrite(str(mixed / "a.png"), _frame(0))
    cv2.imwrite(str(mixed / "b.png"), _frame(1, size=(32, 24)))
    with VideoFileCamera(mixed, fps=25) as cam:
        cam.read()
        with pytest.raises(ValueError, match=r"b\.png is 32x24, but the folder's first image is 64x48"):
            cam.read()
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "a.png").write_bytes(b"not a png")
    with pytest.raises(ValueError, match=r"a\.png cannot be read"):
        VideoFileCamera(broken, fps=25)


def test_missing_and_unreadable_files(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="nothing.mp4"):
        VideoFileCamera(tmp_path / "nothing.mp4")
    fake = tmp_path / "fake.mp4"
    fake.write_text("this is text, not a video\n" * 20)
    with pytest.raises(ValueError, match="cannot be opened as a video"):
        VideoFileCamera(fake)
    for bad in (0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="fps must be a positive finite number"):
            VideoFileCamera(tmp_path, fps=bad)


def test_truncated_video_raises_or_warns(tmp_path: Path) -> None:
    # AVI keeps its header (30 frames) at the start, so a cut file opens and its frames stop early.
    full = _write_video(tmp_path / "full.avi", 30, 25.0, "MJPG")
    cut = tmp_path / "cut.avi"
    data = full.read_bytes()
    cut.write_bytes(data[: int(len(data) * 0.6)])
    with VideoFileCamera(cut) as cam:
        assert cam.frame_count == 30
        frames = []
        with pytest.raises(
            TruncatedVideoError, match=r"ended after (\d+) frames, but its header promises 30"
        ):
            while True:
                frame = cam.read()
                assert frame is not None
                frames.append(frame)
    assert 0 < len(frames) < 30
    with VideoFileCamera(cut, strict=False) as cam:
        with pytest.warns(UserWarning, match=f"ended after {len(frames)} frames"):
            assert len(list(cam)) == len(frames)
    # The complete file reads without complaint.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with VideoFileCamera(full) as cam:
            assert len(list(cam)) == 30


def test_truncated_mp4_cannot_be_opened(tmp_path: Path) -> None:
    # OpenCV's MP4 writer puts the index (moov atom) last: a cut MP4 is not a video any more.
    full = _write_video(tmp_path / "full.mp4", 30, 25.0, "mp4v")
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(full.read_bytes()[: full.stat().st_size // 2])
    with pytest.raises(ValueError, match="cannot be opened as a video"):
        VideoFileCamera(cut)


# ------------------------------------------------------------------------------------------------ devices


def test_device_camera_reads_a_stream_and_stamps_monotonic_time(tmp_path: Path) -> None:
    path = _write_video(tmp_path / "stream.mp4", 6, 25.0, "mp4v")
    with OpenCVDeviceCamera(str(path)) as cam:
        assert isinstance(cam, Camera)
        frames = list(cam)
    assert [f.index for f in frames] == list(range(6))
    _assert_is_frame_k(frames[2].rgb, 2)
    times = [f.t_capture for f in frames]
    assert times == sorted(times)


def test_device_camera_that_does_not_open() -> None:
    with pytest.raises(ValueError, match="cannot open camera device 99"):
        OpenCVDeviceCamera(99)


@pytest.mark.ci_may_skip("the test is of the error without pyrealsense2")
@pytest.mark.skipif(importlib.util.find_spec("pyrealsense2") is not None, reason="pyrealsense2 is installed")
def test_realsense_without_sdk_says_how_to_install() -> None:
    with pytest.raises(ImportError, match="pip install pyrealsense2"):
        RealSenseCamera()
