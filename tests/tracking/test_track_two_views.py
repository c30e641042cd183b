"""``dyndlo-vision track`` with two cameras: a cable that swings out of any one plane, seen from two
calibrated views and triangulated (``--second-video``)."""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest

from dyndlo_vision.cli import main
from dyndlo_vision.tracking.annotate import inset_view
from dyndlo_vision.tracking.camera_model import PinholeCamera
from dyndlo_vision.tracking.synthetic import render_cable

from .helpers import assert_track_refuses, look_at_camera

FPS = 25.0
N_FRAMES = 30
LENGTH_M = 0.5
HELD_Z = 0.6
#: Frames in which a pole hides the cable's lower half from the second camera.
HIDDEN_IN_SECOND = (12, 13, 14)
#: The 6 px line's skeleton stops up to ~4 px short of its rounded end in each view (test_track_cli.py), about
#: 8 mm at these cameras' 1.1-1.3 m; the triangulated tip inherits it from both views, and the CSV's x,y,z is
#: the Kalman filter's estimate of a swinging tip. Measured on this clip: tip 9 mm median, 15.5 mm at most;
#: held end 5 mm median, 8 mm at most. One camera on the same clip: over 100 mm.
TIP_TOL_M = 0.02
MEDIAN_TOL_M = 0.012


def cable_world(t: float) -> np.ndarray:
    """(300, 3) points of a cable held at a moving end that swings in x *and* y (out of the plane y = 0 by up
    to 0.13 m), held end first."""
    s = np.linspace(0.0, LENGTH_M, 300)
    ds = np.diff(s, prepend=0.0)
    bend = (0.3 + 0.7 * s / LENGTH_M)
    ax = 0.5 * np.sin(2 * np.pi * 0.8 * t) * bend  # swing towards x
    ay = 0.4 * np.sin(2 * np.pi * 0.5 * t + 0.6) * bend  # and towards the cameras (y)
    x = 0.05 * np.sin(np.pi * t) + np.cumsum(np.sin(ax) * np.cos(ay) * ds)
    y = np.cumsum(np.sin(ay) * ds)
    z = HELD_Z - np.cumsum(np.cos(ax) * np.cos(ay) * ds)
    return np.column_stack((x, y, z))


@dataclass(frozen=True)
class StereoClip:
    video_a: Path
    video_b: Path
    calib_a: Path
    calib_b: Path
    cam_a: PinholeCamera
    cam_b: PinholeCamera
    tips: np.ndarray
    held: np.ndarray
    middle: np.ndarray


def _write(path: Path, frames: list[np.ndarray], fps: float = FPS) -> Path:
    h, w = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
    for rgb in frames:
        writer.write(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    writer.release()
    return path


def _render(camera: PinholeCamera, curves: list[np.ndarray], hide_lower: tuple[int, ...] = ()) -> list:
    frames = []
    for k, c in enumerate(curves):
        rgb, _ = render_cable(camera.project(c), (camera.height, camera.width), thickness=6,
                              color=(40, 40, 40), background=(200, 200, 200), seed=k)
        if k in hide_lower:  # a grey pole, the wall's colour: the cable's lower half is not seen
            v_mid = float(camera.project(c[150:151])[0, 1])
            rgb[int(v_mid):] = 200
        frames.append(rgb)
    return frames


@pytest.fixture(scope="module")
def clip(tmp_path_factory: pytest.TempPathFactory) -> StereoClip:
    root = tmp_path_factory.mktemp("stereo")
    cam_a = look_at_camera(eye=(0.05, -1.1, 0.4), target=(0.0, 0.0, 0.35))  # in front
    cam_b = look_at_camera(eye=(0.95, -0.7, 0.75), target=(0.0, 0.0, 0.35))  # right, higher
    curves = [cable_world(k / FPS) for k in range(N_FRAMES)]
    video_a = _write(root / "a.mp4", _render(cam_a, curves))
    video_b = _write(root / "b.mp4", _render(cam_b, curves, HIDDEN_IN_SECOND))
    calib_a, calib_b = root / "a.json", root / "b.json"
    cam_a.to_json(calib_a)
    cam_b.to_json(calib_b)
    return StereoClip(video_a, video_b, calib_a, calib_b, cam_a, cam_b,
                      np.array([c[-1] for c in curves]), np.array([c[0] for c in curves]),
                      np.array([c[len(c) // 2] for c in curves]))


def _anchor(cam: PinholeCamera, p: np.ndarray) -> str:
    u, v = cam.project(p[None])[0]
    return f"{u:.0f},{v:.0f}"


def _stereo_args(clip: StereoClip) -> list[str]:
    return [str(clip.video_a), "--calib", str(clip.calib_a), "--second-video", str(clip.video_b),
            "--second-calib", str(clip.calib_b), "--anchor", _anchor(clip.cam_a, clip.held[0]),
            "--second-anchor", _anchor(clip.cam_b, clip.held[0]), "--background", "frame", "--quiet"]


def _read(path: Path, xyz_columns: tuple[str, ...] = ("x", "y", "z")) -> tuple[np.ndarray, ...]:
    with open(path, newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    visible = np.array([r["visible"] == "1" for r in rows])
    xyz = np.array([[float(r[c]) if r[c] else np.nan for c in xyz_columns] for r in rows])
    uv = np.array([[float(r[c]) if r[c] else np.nan for c in "uv"] for r in rows])
    return visible, xyz, uv


def test_the_cable_really_leaves_the_plane() -> None:
    """The premise: one camera with a plane cannot place this cable (its tip is up to 0.13 m off y = 0)."""
    off = np.array([abs(cable_world(k / FPS)[-1, 1]) for k in range(N_FRAMES)])
    assert off.max() > 0.12


def test_two_views_triangulate_the_tip(clip: StereoClip, tmp_path: Path,
                                       capsys: pytest.CaptureFixture) -> None:
    out, annotated = tmp_path / "two.csv", tmp_path / "two.mp4"
    assert main(["track", *_stereo_args(clip), "--out", str(out), "--annotated", str(annotated)]) == 0
    captured = capsys.readouterr()
    assert "(world, m, two views)" in captured.out
    visible, xyz, uv = _read(out)
    # The frames whose lower half the second camera does not see: the far end of what both views saw is not
    # the tip, so it is not measured (and the run says so).
    assert not visible[list(HIDDEN_IN_SECOND)].any()
    reason = "the triangulated cable does not reach its far end in both views"
    assert f"{reason} ({len(HIDDEN_IN_SECOND)})" in captured.err
    others = np.setdiff1d(np.arange(N_FRAMES), HIDDEN_IN_SECOND)
    assert visible[others].all()
    err = np.linalg.norm(xyz[visible] - clip.tips[visible], axis=1)
    assert err.max() < TIP_TOL_M and np.median(err) < MEDIAN_TOL_M, err
    # The unfiltered triangulated tip (measured on this clip: 10.1 mm median, 15.8 at most; the line's
    # skeleton stops short of its rounded end in both views).
    _, raw, _ = _read(out, ("x_meas", "y_meas", "z_meas"))
    err = np.linalg.norm(raw[visible] - clip.tips[visible], axis=1)
    assert err.max() < TIP_TOL_M and np.median(err) < MEDIAN_TOL_M, err
    assert np.all(np.isnan(raw[~visible]))
    # u,v is the measured tip's pixel in the first view.
    err_px = np.linalg.norm(uv[visible] - clip.cam_a.project(clip.tips[visible]), axis=1)
    assert err_px.max() < 8.0, err_px
    # Inner points: the held end (the centrelines' triangulated start), and the cable's middle by arc length.
    for point, truth in (("0", clip.held), ("0.5", clip.middle)):
        path = tmp_path / f"point{point}.csv"
        assert main(["track", *_stereo_args(clip), "--point", point, "--out", str(path)]) == 0
        seen, at, _ = _read(path)
        assert seen[others].all()
        err = np.linalg.norm(at[seen] - truth[seen], axis=1)
        assert err.max() < TIP_TOL_M and np.median(err) < MEDIAN_TOL_M, (point, err)
    # One view on the same video, lifting onto y = 0, is far off: the second view is what places the cable.
    one = tmp_path / "one.csv"
    assert main(["track", str(clip.video_a), "--calib", str(clip.calib_a), "--plane", "0,1,0,0", "--anchor",
                 _anchor(clip.cam_a, clip.held[0]), "--quiet", "--out", str(one)]) == 0
    visible1, xyz1, _ = _read(one)
    assert np.nanmax(np.linalg.norm(xyz1[visible1] - clip.tips[visible1], axis=1)) > 0.1
    # The annotated video has the first view's size, with the second view inset at its top right.
    cap = cv2.VideoCapture(str(annotated))
    ok, first = cap.read()
    n = 1
    while cap.read()[0]:
        n += 1
    cap.release()
    assert ok and n == N_FRAMES and first.shape == (480, 640, 3)
    raw_b = cv2.VideoCapture(str(clip.video_b))
    _, frame_b = raw_b.read()
    raw_b.release()
    inset = first[480 - 160:, 640 - 213:]
    expected = cv2.resize(frame_b, (213, 160), interpolation=cv2.INTER_AREA)
    # The same picture (the overlay's lines and label differ in a minority of pixels).
    assert np.median(np.abs(inset.astype(int) - expected.astype(int))) < 10


def test_two_views_with_the_cable_length_and_a_tcp_log(clip: StereoClip, tmp_path: Path,
                                                       capsys: pytest.CaptureFixture) -> None:
    """With the gripper's log as the held end and the cable's length, a tip hidden from one view is continued
    from what both saw, as with one view; elsewhere it is the triangulated end."""
    log = tmp_path / "tcp.csv"
    log.write_text("time_s,x,y,z\n" + "".join(f"{k / FPS},{p[0]},{p[1]},{p[2]}\n"
                                              for k, p in enumerate(clip.held)))
    out = tmp_path / "len.csv"
    args = [str(clip.video_a), "--calib", str(clip.calib_a), "--second-video", str(clip.video_b),
            "--second-calib", str(clip.calib_b), "--tcp-log", str(log), "--cable-length", str(LENGTH_M),
            "--quiet", "--out", str(out)]
    assert main(["track", *args]) == 0
    err_text = capsys.readouterr().err
    assert "the gripper was masked and taken as the held end in 30 of 30 frames" in err_text
    visible, xyz, _ = _read(out)
    others = np.setdiff1d(np.arange(N_FRAMES), HIDDEN_IN_SECOND)
    assert visible[others].all()
    err = np.linalg.norm(xyz[others] - clip.tips[others], axis=1)
    assert err.max() < TIP_TOL_M, err
    # Half the cable seen by both: the tip is continued straight from there (a swinging cable is curved, so
    # this is rough), or not measured; never a point on the visible half taken for the tip.
    hidden = list(HIDDEN_IN_SECOND)
    if visible[hidden].any():
        far = np.linalg.norm(xyz[hidden] - clip.held[hidden], axis=1)[visible[hidden]]
        assert np.all(far > 0.8 * LENGTH_M), far


def _frames_of(video: Path) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(video))
    frames = []
    while True:
        ok, bgr = cap.read()
        if not ok:
            break
        frames.append(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
    cap.release()
    return frames


TWO = ["--second-video", "{b}", "--calib", "{ca}", "--second-calib", "{cb}"]
BAD = {
    "second video without its calibration": (["--second-video", "{b}", "--calib", "{ca}"], "--second-calib"),
    "second calibration without a video": (
        ["--calib", "{ca}", "--plane", "0,1,0,0", "--second-calib", "{cb}"], "--second-calib is for the"
    ),
    "second anchor without a video": (["--second-anchor", "1,1"], "--second-anchor is for the second"),
    "a plane with two views": ([*TWO, "--plane", "0,1,0,0"], "drop --plane"),
    "the same video twice": (["--second-video", "{a}", "--calib", "{ca}", "--second-calib", "{cb}"],
                             "the two views must differ"),
    "one camera twice": (["--second-video", "{b}", "--calib", "{ca}", "--second-calib", "{ca}"],
                         "share their optical centre"),
    "second calibration of another size": (["--second-video", "{b}", "--calib", "{ca}", "--second-calib",
                                            "{small}"], "--second-calib .* is for 320x240 images"),
    "second anchor outside": ([*TWO, "--second-anchor", "900,10"], "--second-anchor 900,10 is outside"),
    "second video shorter": ([*TWO], "ended after 20 frames"),
    "second video longer": ([*TWO], "goes on: the two views"),
    "second video at another rate": ([*TWO], "runs at 12.5 fps"),
    "tcp log and a second anchor": ([*TWO, "--tcp-log", "{log}", "--second-anchor", "1,1"],
                                    "drop --second-anchor"),
    "writing over the second video": ([*TWO, "--annotated", "{b}"], "is an input video"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_two_view_input_exits_2_and_writes_nothing(case: str, clip: StereoClip, tmp_path: Path,
                                                      capsys: pytest.CaptureFixture) -> None:
    inputs = tmp_path / "in"
    inputs.mkdir()
    small = inputs / "small.json"
    look_at_camera(width=320, height=240).to_json(small)
    log = inputs / "tcp.csv"
    log.write_text("time_s,x,y,z\n0,0,0,0.6\n10,0,0,0.6\n")
    values = {"a": str(clip.video_a), "b": str(clip.video_b), "ca": str(clip.calib_a),
              "cb": str(clip.calib_b), "small": str(small), "log": str(log)}
    # The second video, edited: 20 of its 30 frames, 5 frames more, or another frame rate.
    edits = {"second video shorter": lambda f: (f[:20], FPS),
             "second video longer": lambda f: (f + f[:5], FPS),
             "second video at another rate": lambda f: (f, 12.5)}
    if case in edits:
        frames, fps = edits[case](_frames_of(clip.video_b))
        values["b"] = str(_write(inputs / "edited.mp4", frames, fps=fps))
    outputs = tmp_path / "out"
    outputs.mkdir()
    template, message = BAD[case]
    argv = [str(clip.video_a), *(a.format(**values) for a in template), "--out", str(outputs / "t.csv"),
            "--quiet"]
    if "--annotated" not in argv:
        argv += ["--annotated", str(outputs / "t.mp4")]
    assert_track_refuses(argv, message, outputs, capsys)


def test_inset_view_puts_the_second_view_top_right() -> None:
    base = np.zeros((480, 640, 3), np.uint8)
    view = np.full((240, 320, 3), (10, 200, 30), np.uint8)
    out = inset_view(base, view, label="")
    assert out.shape == base.shape and not base.any()  # a copy
    assert np.all(out[480 - 155:475, 640 - 208:635] == (10, 200, 30))
    assert not out[:300, :].any() and not out[:, :400].any()
    top = inset_view(base, view, label="", corner="top-right")
    assert np.all(top[5:155, 640 - 208:635] == (10, 200, 30)) and not top[200:].any()
    with pytest.raises(ValueError, match="corner"):
        inset_view(base, view, corner="left")
    with pytest.raises(ValueError, match="fraction"):
        inset_view(base, view, fraction=0)
    with pytest.raises(ValueError, match="view must be"):
        inset_view(base, view[..., 0])


def test_without_anchors_the_second_view_takes_the_end_on_the_held_ends_epipolar_line(
        clip: StereoClip, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """Without anchors each view must choose which cable end is held. The first takes the upper end (a hanging
    cable's). A second camera rolled upside down sees the held end at the bottom, so "the upper end" would be
    the tip there; the end on the epipolar line of the first view's held end is the held end in any pose."""
    flip = np.diag([-1.0, -1.0, 1.0])  # 180 degrees about the optical axis
    cam_b = clip.cam_b
    rolled = PinholeCamera(cam_b.width, cam_b.height, cam_b.K, cam_b.dist, flip @ cam_b.R, flip @ cam_b.t,
                           fps=cam_b.fps)
    curves = [cable_world(k / FPS) for k in range(N_FRAMES)]
    video_b = _write(tmp_path / "rolled.mp4", _render(rolled, curves))
    calib_b = tmp_path / "rolled.json"
    rolled.to_json(calib_b)
    assert rolled.project(clip.held[:1])[0, 1] > rolled.project(clip.tips[:1])[0, 1]  # held end below the tip
    out = tmp_path / "t.csv"
    assert main(["track", str(clip.video_a), "--calib", str(clip.calib_a), "--second-video", str(video_b),
                 "--second-calib", str(calib_b), "--background", "frame", "--quiet", "--out", str(out)]) == 0
    err_text = capsys.readouterr().err
    assert "took the cable end on the epipolar line of the first view's held end" in err_text
    visible, xyz, _ = _read(out, ("x_meas", "y_meas", "z_meas"))
    assert visible.mean() > 0.9
    err = np.linalg.norm(xyz[visible] - clip.tips[visible], axis=1)
    assert np.median(err) < MEDIAN_TOL_M and err.max() < TIP_TOL_M, err


def _distance_to_curve(points: np.ndarray, curve: np.ndarray) -> np.ndarray:
    """Each point's distance to the nearest vertex of a densely sampled curve (300 points over 0.5 m)."""
    return np.min(np.linalg.norm(points[:, None, :] - curve[None, :, :], axis=2), axis=1)


def test_nodes_out_writes_the_whole_triangulated_cable(clip: StereoClip, tmp_path: Path) -> None:
    """``--nodes-out``: every node of every frame, node 0 at the held end; with two cameras the triangulated
    nodes lie on the true 3D cable (measured: 0.8 mm median, 2.5 mm at most, to the nearest true point; node 0
    5.5 mm from the held end, median)."""
    nodes = tmp_path / "nodes.csv"
    assert main(["track", *_stereo_args(clip), "--nodes", "15", "--out", str(tmp_path / "t.csv"),
                 "--nodes-out", str(nodes)]) == 0
    with open(nodes, newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        assert reader.fieldnames == ["frame", "time_s", "node", "visible", "u", "v", "x", "y", "z"]
        rows = list(reader)
    assert len(rows) == 15 * N_FRAMES
    assert [int(r["node"]) for r in rows[:15]] == list(range(15))
    dists, held_err = [], []
    for k in range(N_FRAMES):
        frame = [r for r in rows if int(r["frame"]) == k]
        seen = [r for r in frame if r["visible"] == "1"]
        assert seen, k
        xyz = np.array([[float(r[c]) for c in "xyz"] for r in seen])
        dists.append(_distance_to_curve(xyz, cable_world(k / FPS)))
        if frame[0]["visible"] == "1":
            held_err.append(np.linalg.norm(xyz[0] - clip.held[k]))
    d = np.concatenate(dists)
    assert np.median(d) < 0.004 and d.max() < 0.012, (np.median(d), d.max())
    assert np.median(held_err) < 0.01


def test_nodes_out_must_be_its_own_file(clip: StereoClip, tmp_path: Path,
                                        capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "out"
    out.mkdir()
    cases = ((out / "t.csv", "another output's file"), (out / "no" / "n.csv", "does not exist"))
    for nodes, message in cases:
        assert_track_refuses([*_stereo_args(clip), "--out", str(out / "t.csv"), "--nodes-out", str(nodes)],
                             re.escape(message), out, capsys)
