"""Atomic file writes: outputs appear whole or not at all, with the modes a plain ``open`` would give them."""

from __future__ import annotations

import os
import shutil
import signal
import tempfile
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

_UMASK_LOCK = threading.Lock()


def current_umask() -> int:
    """The process' file mode creation mask, read without changing it where the OS allows.

    ``os.umask`` can only read the mask by setting another one, which would briefly change the mode of files
    that other threads create; Linux reports the mask in ``/proc/self/status``, so that is read first.
    """
    try:
        with open("/proc/self/status", encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    # Elsewhere: set a placeholder and put the mask back. 0o077 is the safe placeholder (a file another thread
    # creates meanwhile is private, not public); the lock keeps two readers from restoring each other's.
    with _UMASK_LOCK:
        mask = os.umask(0o077)
        os.umask(mask)
    return mask


def write_atomic(path: Path, write: Callable[[str], Any]) -> None:
    """Write via a temporary file in the same folder, then rename: no partial outputs on failure.

    The file gets the mode a plain ``open(path, "w")`` would give a new file (``0o666`` less the umask):
    ``tempfile.mkstemp`` creates its files ``0o600``, private to the owner, which outputs are not meant to be.

    Args:
        path: The file to (over)write.
        write: Writes the content to the temporary path it is given.
    """
    path = Path(path)
    # A dot-name with the target's name in it: a partial file left by a killed process is hidden and says
    # what it was; the suffix is kept because some writers (OpenCV, matplotlib) choose the format by it.
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=path.suffix)
    os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, 0o666 & ~current_umask())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def check_output_file(path: Path, option: str = "--out", example: str = "out.json") -> Path:
    """Check that ``path`` can name an output file before any work is done; returns it as a Path.

    Raises:
        ValueError: ``path`` is an existing folder, or the folder that would hold it does not exist.
    """
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{option} {path} is a folder; expected a file name such as {path / example}")
    if not path.parent.is_dir():
        raise ValueError(f"{option} {path}: folder {path.parent} does not exist")
    return path


def check_output_folder(folder: Path, option: str = "--out") -> None:
    """Check that ``folder`` can be an output folder (existing or new) before any work is done.

    Raises:
        ValueError: ``folder`` is an existing file, one of its ancestors is a file, or the folder that would
            hold it is not writable.
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"{option} {folder} is an existing file; expected a folder (existing or new)")
    anchor = _existing_ancestor(folder)
    if not anchor.is_dir():
        raise ValueError(f"{option} {folder}: {anchor} is a file, so no folder can be created under it")
    if not os.access(anchor, os.W_OK | os.X_OK):
        raise ValueError(f"{option} {folder}: cannot write in {anchor} (permission denied)")


@contextmanager
def staged_folder(folder: Path) -> Iterator[Path]:
    """Write a set of outputs into a staging folder; they land in ``folder`` together, or not at all.

    Yields an empty staging folder next to where ``folder`` is (same file system, so moves are renames).
    When the block ends normally its files move into ``folder``: a new ``folder`` appears by one rename,
    with its files in it; in an existing one each file replaces its namesake. When the block raises, the
    staging folder is removed and nothing, not even an empty ``folder``, is left behind.

    Raises:
        ValueError: ``folder`` cannot be an output folder (see :func:`check_output_folder`).
    """
    folder = Path(folder)
    check_output_folder(folder)
    anchor = folder if folder.is_dir() else _existing_ancestor(folder)
    stage = Path(tempfile.mkdtemp(dir=anchor, prefix=f".{folder.name}.staging-"))
    try:
        yield stage
        if folder.is_dir():
            for item in sorted(stage.iterdir()):
                target = folder / item.name
                if item.is_dir() and target.is_dir():  # a folder of outputs replaces its namesake whole
                    old = Path(tempfile.mkdtemp(dir=folder, prefix=f".{item.name}.old-")) / item.name
                    os.rename(target, old)
                    os.rename(item, target)
                    shutil.rmtree(old.parent, ignore_errors=True)
                else:
                    os.replace(item, target)
            stage.rmdir()
        else:
            folder.parent.mkdir(parents=True, exist_ok=True)
            # mkdtemp makes a private (0o700) folder; a new output folder gets the mode mkdir would give it.
            os.chmod(stage, 0o777 & ~current_umask())
            os.rename(stage, folder)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)  # our own temporary folder, nothing else
        raise


def _existing_ancestor(path: Path) -> Path:
    """``path`` itself if it exists, else its nearest existing ancestor (``.`` for a relative path)."""
    path = Path(path)
    for candidate in (path, *path.parents):
        if candidate.exists():
            return candidate
    return Path(".")


@contextmanager
def interrupts_held() -> Iterator[None]:
    """Hold SIGINT and SIGTERM for the block; if one came, raise KeyboardInterrupt when the block is done.

    For checkpoint writes. A Ctrl-C that lands inside torch's zip writer cuts the file, and the writer's
    clean-up then raises its own RuntimeError in place of the KeyboardInterrupt: ``train`` exited 1 instead
    of 130, with no resume hint (seen in CI). Outside the main thread, where signals cannot be
    handled, the block runs as it is.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    held = (signal.SIGINT, signal.SIGTERM)
    previous = {s: signal.getsignal(s) for s in held}
    for s in held:
        signal.signal(s, lambda signum, frame: caught.append(signum))
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler if handler is not None else signal.SIG_DFL)
    if caught:
        raise KeyboardInterrupt(f"signal {caught[0]}, held until the checkpoint was written")
