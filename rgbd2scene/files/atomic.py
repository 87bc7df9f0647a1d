"""Atomic file output: write to a temporary name in the same folder, then rename into place."""

from __future__ import annotations

import contextlib
import json
import os
import re
import secrets
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

#: Names :func:`atomic_path` gives its temporary files: ``.NAME.<8 hex digits><suffix>``.
TEMPORARY_NAME = re.compile(r"^\..+\.[0-9a-f]{8}(\.\w+)?$")


@contextlib.contextmanager
def atomic_path(path: str | Path, suffix: str | None = None, tmp_dir: str | Path | None = None) -> Iterator[Path]:
    """Yield a temporary path; on success it is renamed onto ``path``, on error removed.

    The temporary file is ``.NAME.<random><suffix>`` next to ``path`` (or in ``tmp_dir``, which must be on
    the same file system). ``suffix`` defaults to the target's own suffix, so writers that pick a format
    from the file extension (OpenCV, Open3D) keep working. It is created with mode 0o666 less the
    process umask, like any new file.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    folder = Path(tmp_dir) if tmp_dir is not None else path.parent
    while True:
        tmp = folder / f".{path.stem}.{secrets.token_hex(4)}{suffix or path.suffix}"
        try:
            os.close(os.open(tmp, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
            break
        except FileExistsError:
            continue
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def sweep_temporaries(folder: str | Path) -> int:
    """Remove the temporary files that killed :func:`atomic_path` writers left in ``folder`` (not below it).

    Only call it where no writer can be alive (e.g. under a lock of the whole output); returns the count.
    """
    count = 0
    for path in Path(folder).glob(".*"):
        if TEMPORARY_NAME.match(path.name) and path.is_file():
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
                count += 1
    return count


def link_or_copy(src: str | Path, dst: str | Path) -> None:
    """Hard-link ``src`` at ``dst`` (no extra disk space), or copy it where a link cannot be made (another file
    system). Meant for files that are only ever replaced (atomic writes rename a new file into place, which
    unlinks rather than changes the shared one), never edited in place."""
    dst = Path(dst)
    dst.unlink(missing_ok=True)
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def _umask() -> int:
    """The process umask, read without changing it (``/proc``), else by setting and restoring it."""
    with contextlib.suppress(OSError, ValueError), open("/proc/self/status") as f:
        for line in f:
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_place(path: str | Path) -> Iterator[Path]:
    """Yield ``path``'s name inside a fresh hidden folder next to it; on success, what was written there (a file
    or a whole folder, e.g. a ROS 2 bag) replaces ``path``. On error, or if nothing was written, it is removed.

    Writers that insist on creating their output themselves (and name inner files after it) write the real
    name, so nothing inside keeps a temporary name; an existing folder at ``path`` is swapped out, then deleted.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
    try:
        tmp = work / path.name
        yield tmp
        if tmp.is_dir() and path.is_dir():
            os.replace(path, work / ".old")  # a folder cannot be renamed onto a non-empty folder
        if tmp.exists():
            if tmp.is_dir():
                os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp made it owner-only
            os.replace(tmp, path)
    finally:
        shutil.rmtree(work, ignore_errors=True)


def ensure_output_dir(out_dir: str | Path) -> Path:
    """Create ``out_dir`` (and parents) and prove it writable, or raise a one-line ``UserError``."""
    from rgbd2scene.errors import UserError

    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise UserError(f"{out}: output path exists and is not a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=out, prefix=".write-test."):
            pass
    except OSError as exc:
        raise UserError(f"{out}: output folder is not writable ({exc.strerror or exc})") from None
    return out


def write_bytes(path: str | Path, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text(path: str | Path, text: str) -> None:
    write_bytes(path, text.encode())


def read_json_object(path: str | Path, what: str = "JSON file") -> dict:
    """The JSON object in ``path``; a one-line ``UserError`` naming the file when it is unreadable, not JSON
    or not an object (``what`` says what the file should be)."""
    from rgbd2scene.errors import UserError

    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise UserError(f"{path}: not a readable {what} ({exc})") from None
    if not isinstance(data, dict):
        raise UserError(f"{path}: a {what} must hold a JSON object")
    return data


def write_json(path: str | Path, obj) -> None:
    write_text(path, json.dumps(obj, indent=2, default=_json_default) + "\n")


def write_npy(path: str | Path, array: np.ndarray) -> None:
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.save(f, array)


def _json_default(obj):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")
