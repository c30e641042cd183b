"""Every video the package writes: H.264 (yuv420p) through PyAV, MPEG-4 Part 2 only as the fallback, with the
codec it used reported; whole files or none."""

from __future__ import annotations

from pathlib import Path

import av
import cv2
import numpy as np
import pytest

from dyndlo_vision._video import VideoWriter, write_video_atomic


def frames(n: int = 5, h: int = 48, w: int = 64) -> list[np.ndarray]:
    """Frames with a bright square moving right on a dark ramp (RGB)."""
    out = []
    for k in range(n):
        frame = np.zeros((h, w, 3), np.uint8)
        frame[..., 2] = np.linspace(0, 120, w, dtype=np.uint8)[None, :]
        frame[10:20, 4 * k:4 * k + 10] = (250, 40, 40)
        out.append(frame)
    return out


def probe(path: Path) -> tuple[str, str, int, tuple[int, int], float]:
    """Codec name, pixel format, frames decoded, (width, height) and frame rate, as PyAV reads the file."""
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        n = sum(1 for _ in container.decode(stream))
        return (stream.codec_context.name, stream.codec_context.pix_fmt, n, (stream.width, stream.height),
                float(stream.average_rate))


def test_videos_are_h264_yuv420p_that_opencv_reads_back(tmp_path: Path) -> None:
    src = frames(25)
    assert write_video_atomic(tmp_path / "v.mp4", src, fps=25.0) == "h264"
    assert probe(tmp_path / "v.mp4") == ("h264", "yuv420p", 25, (64, 48), 25.0)
    cap = cv2.VideoCapture(str(tmp_path / "v.mp4"))
    ok, first = cap.read()
    assert ok and first.shape == (48, 64, 3)
    # RGB in, BGR read back: the red square is red (channel order kept), within the codec's loss
    assert first[15, 8, 2] > 200 and first[15, 8, 0] < 90
    assert np.abs(first.astype(int) - src[0][..., ::-1]).mean() < 4


def test_odd_sizes_get_one_more_row_and_column(tmp_path: Path) -> None:
    with VideoWriter(tmp_path / "odd.mp4", 10.0, (63, 47)) as writer:
        for frame in frames(3, 47, 63):
            writer.write(np.ascontiguousarray(frame[..., ::-1]))
    assert writer.codec == "h264" and writer.frames == 3
    assert probe(tmp_path / "odd.mp4")[1:4] == ("yuv420p", 3, (64, 48))


def test_mp4v_is_the_fallback_and_is_reported(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def no_h264(self: VideoWriter) -> None:
        raise RuntimeError("this PyAV has no libx264 encoder")

    monkeypatch.setattr(VideoWriter, "_open_h264", no_h264)
    assert write_video_atomic(tmp_path / "v.mp4", frames(3)) == "mp4v"
    assert probe(tmp_path / "v.mp4")[0] == "mpeg4"
    assert int(cv2.VideoCapture(str(tmp_path / "v.mp4")).get(cv2.CAP_PROP_FRAME_COUNT)) == 3
    # with neither, a clear error naming both reasons, and no file
    monkeypatch.setattr(VideoWriter, "_open_mp4v", no_h264)
    with pytest.raises(ValueError, match=r"cannot write an MP4 video to .*h264: this PyAV.*mp4v: this PyAV"):
        write_video_atomic(tmp_path / "w.mp4", frames(3))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.mp4"]


def test_video_rejects_frames_it_would_silently_drop(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="no frames"):
        write_video_atomic(tmp_path / "v.mp4", [])
    with pytest.raises(ValueError, match=r"frame 2 is \(40, 64, 3\) uint8; expected \(48, 64, 3\) uint8"):
        write_video_atomic(tmp_path / "v.mp4", [*frames(2), np.zeros((40, 64, 3), np.uint8)])
    assert list(tmp_path.iterdir()) == []
    with VideoWriter(tmp_path / "s.mp4", 25.0, (64, 48)) as writer:
        with pytest.raises(ValueError, match=r"frame 0 is \(48, 64\) uint8"):
            writer.write(np.zeros((48, 64), np.uint8))
    for bad in ({"fps": 0.0}, {"size": (0, 48)}, {"codecs": ("avc1",)}, {"codecs": ()}):
        with pytest.raises(ValueError):
            VideoWriter(tmp_path / "b.mp4", **{"fps": 25.0, "size": (64, 48), **bad})



def test_track_annotated_is_h264(tmp_path: Path) -> None:
    """``track --annotated`` writes through the same writer: H.264, one frame per input frame."""
    from dyndlo_vision.cli import main

    clip = tmp_path / "clip"
    clip.mkdir()
    for k in range(6):  # a dark cable hanging from (80, 20), swinging, on a light wall
        image = np.full((120, 160, 3), 220, np.uint8)
        cv2.line(image, (80, 20), (80 + 6 * k - 15, 100), (30, 30, 30), 3)
        cv2.imwrite(str(clip / f"f{k:02d}.png"), image)
    out, annotated = tmp_path / "t.csv", tmp_path / "t.mp4"
    argv = ["track", str(clip), "--fps", "25", "--anchor", "80,20", "--background", "frame", "--quiet"]
    assert main([*argv, "--out", str(out), "--annotated", str(annotated)]) == 0
    assert probe(annotated)[:4] == ("h264", "yuv420p", 6, (160, 120))
