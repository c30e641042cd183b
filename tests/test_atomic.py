"""Atomic writes: whole files with the umask's mode, no partial outputs."""

from __future__ import annotations

import os
import stat
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from dyndlo_vision._atomic import check_output_folder, current_umask, staged_folder, write_atomic
from dyndlo_vision._video import write_video_atomic


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
