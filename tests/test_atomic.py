"""Atomic writes: whole files with the umask's mode, no partial outputs, MP4 with the best codec there is."""

from __future__ import annotations

import os
import stat
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest

from dyndlo_vision import _atomic
from dyndlo_vision._atomic import (
    VIDEO_CODECS,
    check_output_folder,
    current_umask,
    staged_folder,
    video_codec_available,
    write_atomic,
    write_video_atomic,
)

# What OpenCV reports as CAP_PROP_FOURCC when it reads back a file written with each codec.
READ_BACK_FOURCC = {"avc1": {"avc1", "h264", "H264"}, "mp4v": {"FMP4", "mp4v"}, "vp09": {"VP90", "vp09"}}


@pytest.fixture
def umask() -> Iterator[None]:
    """Restore the process' umask after a test that sets its own."""
    saved = os.umask(0o022)
    os.umask(saved)
    try:
        yield
    finally:
        os.umask(saved)


def mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def frames(n: int = 3, h: int = 48, w: int = 64) -> list[np.ndarray]:
    return [np.full((h, w, 3), 40 * k, dtype=np.uint8) for k in range(n)]


@pytest.mark.parametrize("mask", [0o022, 0o077, 0o002])
def test_outputs_get_the_mode_of_the_umask_not_mkstemps_0600(tmp_path: Path, umask: None, mask: int) -> None:
    os.umask(mask)
    assert current_umask() == mask
    assert current_umask() == mask  # reading it left it as it was
    write_atomic(tmp_path / "a.json", lambda p: Path(p).write_text("{}"))
    assert mode(tmp_path / "a.json") == 0o666 & ~mask
    write_video_atomic(tmp_path / "v.mp4", frames())
    assert mode(tmp_path / "v.mp4") == 0o666 & ~mask
    with staged_folder(tmp_path / "new" / "out") as stage:
        write_atomic(stage / "b.txt", lambda p: Path(p).write_text("b"))
    assert mode(tmp_path / "new" / "out") == 0o777 & ~mask  # not mkdtemp's 0700
    assert mode(tmp_path / "new" / "out" / "b.txt") == 0o666 & ~mask


def test_current_umask_without_proc_falls_back_to_os_umask(
    tmp_path: Path, umask: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    os.umask(0o027)
    real_open = open

    def no_proc(file: object, *args: object, **kwargs: object) -> object:
        if str(file).startswith("/proc/"):
            raise FileNotFoundError(file)
        return real_open(file, *args, **kwargs)  # type: ignore[call-overload]

    monkeypatch.setattr("builtins.open", no_proc)
    assert current_umask() == 0o027
    assert current_umask() == 0o027


def test_a_failed_write_leaves_no_file_and_keeps_the_old_one(tmp_path: Path) -> None:
    def half_then_fail(p: str) -> None:
        Path(p).write_text("half")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        write_atomic(tmp_path / "new.json", half_then_fail)
    assert list(tmp_path.iterdir()) == []  # neither the output nor the temporary file
    (tmp_path / "old.json").write_text("old")
    with pytest.raises(OSError, match="disk full"):
        write_atomic(tmp_path / "old.json", half_then_fail)
    assert (tmp_path / "old.json").read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["old.json"]
    write_atomic(tmp_path / "old.json", lambda p: Path(p).write_text("new"))
    assert (tmp_path / "old.json").read_text() == "new"
    assert [p.name for p in tmp_path.iterdir()] == ["old.json"]


def test_staged_folder_lands_whole_or_leaves_nothing(tmp_path: Path) -> None:
    new = tmp_path / "a" / "b" / "out"
    with pytest.raises(RuntimeError, match="plot failed"), staged_folder(new) as stage:
        write_atomic(stage / "demo.mp4", lambda p: Path(p).write_bytes(b"video"))
        raise RuntimeError("plot failed")
    assert list(tmp_path.iterdir()) == []  # no folder, no parents, no staging folder

    with staged_folder(new) as stage:
        write_atomic(stage / "demo.mp4", lambda p: Path(p).write_bytes(b"video"))
        write_atomic(stage / "metrics.json", lambda p: Path(p).write_text("{}"))
    assert sorted(p.name for p in new.iterdir()) == ["demo.mp4", "metrics.json"]
    assert sorted(p.name for p in (tmp_path / "a" / "b").iterdir()) == ["out"]

    # An existing folder: files are replaced together, others kept; a failure changes nothing.
    (new / "notes.txt").write_text("mine")
    with pytest.raises(RuntimeError), staged_folder(new) as stage:
        write_atomic(stage / "demo.mp4", lambda p: Path(p).write_bytes(b"video 2"))
        raise RuntimeError("plot failed")
    assert sorted(p.name for p in new.iterdir()) == ["demo.mp4", "metrics.json", "notes.txt"]
    assert (new / "demo.mp4").read_bytes() == b"video"
    with staged_folder(new) as stage:
        write_atomic(stage / "demo.mp4", lambda p: Path(p).write_bytes(b"video 2"))
    assert sorted(p.name for p in new.iterdir()) == ["demo.mp4", "metrics.json", "notes.txt"]
    assert (new / "demo.mp4").read_bytes() == b"video 2"

    # A folder of outputs (demo --raw-videos' frames) replaces its namesake whole, again and again.
    for frames in (["a.png", "b.png"], ["c.png"]):
        with staged_folder(new) as stage:
            (stage / "raw").mkdir()
            for name in frames:
                (stage / "raw" / name).write_bytes(b"png")
        assert sorted(p.name for p in (new / "raw").iterdir()) == frames
        assert sorted(p.name for p in new.iterdir()) == ["demo.mp4", "metrics.json", "notes.txt", "raw"]


def test_check_output_folder_names_the_file_in_the_way(tmp_path: Path) -> None:
    (tmp_path / "f").write_text("x")
    with pytest.raises(ValueError, match=r"--out .*f is an existing file; expected a folder"):
        check_output_folder(tmp_path / "f")
    with pytest.raises(ValueError, match=r"f is a file, so no folder can be created under it"):
        check_output_folder(tmp_path / "f" / "sub" / "out")
    check_output_folder(tmp_path)
    check_output_folder(tmp_path / "new" / "out")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f"]  # checking creates nothing


def test_video_is_written_with_the_first_codec_the_build_has(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(_atomic, "_codec_cache", {})
    codec = write_video_atomic(tmp_path / "v.mp4", frames(5))
    expected = next(c for c in VIDEO_CODECS if video_codec_available(c))
    assert codec == expected and codec in ("avc1", "mp4v")
    cap = cv2.VideoCapture(str(tmp_path / "v.mp4"))
    fourcc = int(cap.get(cv2.CAP_PROP_FOURCC)).to_bytes(4, "little").decode()
    assert fourcc in READ_BACK_FOURCC[codec]
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 5
    # The order is a preference: a codec listed first that the build has wins over mp4v. (VP9 stands in for
    # H.264, which the opencv-python wheels cannot encode.)
    monkeypatch.setattr(_atomic, "VIDEO_CODECS", ("zzzz", "vp09", "mp4v"))
    if not video_codec_available("vp09"):
        pytest.skip("this OpenCV build has no VP9 encoder either")
    assert write_video_atomic(tmp_path / "v9.mp4", frames(5)) == "vp09"
    cap = cv2.VideoCapture(str(tmp_path / "v9.mp4"))
    assert int(cap.get(cv2.CAP_PROP_FOURCC)).to_bytes(4, "little").decode() in READ_BACK_FOURCC["vp09"]
    assert _atomic._codec_cache["zzzz"] is False


def test_a_codec_that_probed_fine_but_refuses_the_size_falls_back(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(_atomic, "VIDEO_CODECS", ("zzzz", "mp4v"))
    monkeypatch.setattr(_atomic, "_codec_cache", {"zzzz": True, "mp4v": True})
    assert write_video_atomic(tmp_path / "v.mp4", frames(3)) == "mp4v"
    assert int(cv2.VideoCapture(str(tmp_path / "v.mp4")).get(cv2.CAP_PROP_FRAME_COUNT)) == 3


def test_probing_a_missing_encoder_is_silent_and_cached(
    capfd: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(_atomic, "_codec_cache", {})
    capfd.readouterr()
    video_codec_available("avc1")  # FFmpeg and OpenCV print several lines on stderr when it is missing
    video_codec_available("zzzz")
    assert capfd.readouterr().err == ""
    assert set(_atomic._codec_cache) == {"avc1", "zzzz"}
    with pytest.raises(ValueError, match="four characters, got 'h264x'"):
        video_codec_available("h264x")


def test_video_rejects_frames_it_would_silently_drop(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="no frames"):
        write_video_atomic(tmp_path / "v.mp4", [])
    with pytest.raises(ValueError, match=r"frame 2 is \(40, 64, 3\) uint8; expected \(48, 64, 3\) uint8"):
        write_video_atomic(tmp_path / "v.mp4", [*frames(2), np.zeros((40, 64, 3), np.uint8)])
    assert list(tmp_path.iterdir()) == []
