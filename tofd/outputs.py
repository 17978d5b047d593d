"""Output files written atomically: a temp file in the target's directory, fsync, then rename over the target.

A reader sees the old file or the whole new one, never a half-written one; a symlink planted at the target is
replaced by the new file, never followed (rename acts on the directory entry). Output paths and directories are
checked before long work starts (OutputError, a UsageError, names the path and the problem).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import IO

from tofd.errors import UsageError


class OutputError(UsageError):
    """An output path that cannot be written: the message names it and why."""


def check_output_dir(path: str | Path, what: str = "--out") -> Path:
    """Check, creating nothing, that directory `path` is writable or can be created (no file or dangling
    symlink in its place, its nearest existing ancestor a writable directory)."""
    path = Path(path)
    if path.is_symlink() and not path.is_dir():
        raise OutputError(f"{what} {path}: a dangling symlink, not a directory")
    if path.exists() and not path.is_dir():
        raise OutputError(f"{what} {path}: exists and is not a directory")
    existing = next(p for p in (path, *path.absolute().parents) if p.exists())
    if not existing.is_dir():
        raise OutputError(f"{what} {path}: cannot create the directory: {existing} is not a directory")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise OutputError(f"{what} {path}: " + ("the directory is not writable" if existing == path else
                                                f"cannot create the directory: {existing} is not writable"))
    return path


def prepare_output_dir(path: str | Path, what: str = "--out") -> Path:
    """Create directory `path` (and its parents) if needed, after check_output_dir."""
    path = check_output_dir(path, what)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{what} {path}: cannot create the directory: {exc.strerror or exc}") from None
    return path


def check_output_file(path: str | Path, what: str = "--out") -> Path:
    """Check that file `path` can be (re)placed: its directory exists and is writable, and it is no directory."""
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{what} {path}: is a directory, expected a file name")
    parent = path.parent
    if not parent.is_dir():
        raise OutputError(f"{what} {path}: the directory {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputError(f"{what} {path}: the directory {parent} is not writable")
    return path


class AtomicFile:
    """A file object writing to a temp file beside `path`; commit() renames it over `path`, discard() removes it.

    As a context manager: commit on normal exit, discard on an exception.
    """

    def __init__(self, path: str | Path, mode: str = "w", buffering: int = -1):
        self.path = Path(path)
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".tmp", dir=self.path.parent)
        self.tmp_path = Path(tmp)
        self.file: IO = os.fdopen(fd, mode, buffering)

    def write(self, data: str | bytes) -> int:
        return self.file.write(data)

    def commit(self) -> Path:
        """Flush, fsync and rename over the target (permissions 0644 less the umask, like open()); if that fails
        (a full disk), the temp file is removed and the OSError raised."""
        if self.file.closed:
            return self.path
        try:
            self.file.flush()
            os.fsync(self.file.fileno())
            umask = os.umask(0)
            os.umask(umask)
            os.fchmod(self.file.fileno(), 0o666 & ~umask)
            self.file.close()
            os.replace(self.tmp_path, self.path)
        except OSError:
            self.discard()
            raise
        return self.path

    def discard(self) -> None:
        if not self.file.closed:
            try:
                self.file.close()  # flushes what is buffered: may fail on a full disk
            except OSError:
                pass
        self.tmp_path.unlink(missing_ok=True)

    def __enter__(self) -> AtomicFile:
        return self

    def __exit__(self, exc_type: object, *_: object) -> None:
        if exc_type is None:
            self.commit()
        else:
            self.discard()


def temp_path(path: str | Path) -> Path:
    """Where an output that is written for a long time (e.g. a .rrd) grows until it is finished: a hidden name
    beside `path`, unique to this process."""
    path = Path(path)
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


def partial_path(path: str | Path) -> Path:
    """The name an output that could not be finished keeps its readable part under: <stem>.partial<suffix>."""
    path = Path(path)
    return path.with_name(f"{path.stem}.partial{path.suffix}")


def finish_output(tmp: Path, path: Path, finished: bool) -> Path | None:
    """Rename `tmp` to `path` if the output was `finished`, else to partial_path(path) (None if nothing was
    written); no temp file remains either way. Returns where it went."""
    if not tmp.exists():
        return None
    target = path if finished else partial_path(path)
    if not finished and tmp.stat().st_size == 0:
        tmp.unlink()
        return None
    os.replace(tmp, target)
    return target


def write_text(path: str | Path, text: str) -> Path:
    """Write `text` to `path` atomically; returns the path."""
    with AtomicFile(path, "w") as fh:
        fh.write(text)
    return Path(path)


def save_figure(fig: object, path: str | Path, **savefig_kwargs: object) -> Path:
    """Save a matplotlib figure as PNG to `path` atomically."""
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", **savefig_kwargs)  # type: ignore[attr-defined]
    return write_bytes(path, buf.getvalue())


def write_bytes(path: str | Path, data: bytes) -> Path:
    """Write `data` to `path` atomically; returns the path."""
    with AtomicFile(path, "wb") as fh:
        fh.write(data)
    return Path(path)
