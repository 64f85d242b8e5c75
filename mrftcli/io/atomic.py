"""Atomic output files: a reader never sees half a file, a crash never leaves one (tracker issue 29, item 8).

Each helper writes into a temporary file next to the target (same folder, so the same file system)
and renames it over the target with :func:`os.replace`, which is atomic on POSIX and Windows: the
target is the old file or the whole new one, never a prefix. A failed write removes the temporary
file and leaves the target as it was.

* :func:`write_text_atomic`, :func:`write_bytes_atomic`: a whole file from memory;
* :func:`atomic_path`: a temporary path for writers that take a path or a stream (matplotlib's
  ``savefig``, the MCAP writer, pandas' ``to_csv``), renamed when the block ends without an error;
  ``create=False`` for writers that refuse a path that exists (rosbags' ROS 1 bag writer);
* :func:`atomic_directory`: the same for a writer that makes a folder (a ROS 2 bag);
* :func:`check_output_path`: the one check of every output path before the work starts (issue 35):
  never through a symbolic link, never onto an input, a special file or a file or folder the tool
  did not write.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

from ..errors import InputError

__all__ = ["write_text_atomic", "write_bytes_atomic", "atomic_path", "atomic_directory", "check_output_path",
           "looks_like_json", "looks_like_page", "looks_like_figure"]


def is_empty(path: Path) -> bool:
    """An empty file or an empty folder: replacing it loses nothing."""
    if path.is_dir():
        return not any(path.iterdir())
    return path.stat().st_size == 0


def looks_like_json(path: Path) -> bool:
    """A file whose first non-blank byte opens a JSON document (what ``--json FILE`` writes)."""
    with open(path, "rb") as fh:
        head = fh.read(256).lstrip()
    return head[:1] in (b"{", b"[")


def looks_like_page(path: Path) -> bool:
    """An HTML page (what a report writes as its pages)."""
    with open(path, "rb") as fh:
        head = fh.read(512).lstrip().lower()
    return head.startswith((b"<!doctype html", b"<html"))


def looks_like_figure(path: Path) -> bool:
    """A PNG, SVG or PDF file (what a report writes as its figures)."""
    with open(path, "rb") as fh:
        head = fh.read(256)
    return head.startswith((b"\x89PNG", b"%PDF", b"<?xml", b"<svg"))


def check_output_path(path: str | Path, option: str, *, folder: bool = False,
                      ours: Callable[[Path], bool] | None = None, what: str = "",
                      inputs: Iterable[str | Path] = ()) -> Path:
    """Refuse an output path that would write through a link or replace what the tool did not write.

    One rule for every output (``--json``, ``--out``, ``--report``, ``--mcap-out``), checked before the
    work starts (a one-line :class:`~mrftcli.errors.InputError`):

    * a symbolic link is never followed (nor replaced): the file it points at is someone else's;
    * a special file (FIFO, device, socket) and any of the command's ``inputs`` are never written;
    * a file where a folder is written (``folder``) or a folder where a file is, is refused;
    * an existing, non-empty target is replaced only if ``ours(path)`` says the tool wrote it (a ROS 2 bag
      folder with its simulation sidecar, a JSON document); ``what`` names what the tool writes there.

    Examples
    --------
    >>> import tempfile
    >>> folder = Path(tempfile.mkdtemp())
    >>> _ = (folder / "notes.txt").write_text("field notes")
    >>> check_output_path(folder / "notes.txt", "--json", ours=looks_like_json, what="a JSON document")
    Traceback (most recent call last):
    ...
    mrftcli.errors.InputError: --json ...notes.txt: exists and is not a JSON document this tool wrote; not replacing it: remove it or choose another path
    """
    path = Path(path)
    if path.is_symlink():
        raise InputError(f"{option} {path}: is a symbolic link; not writing through it onto another file: "
                         "give the real path")
    if not path.exists():
        return path
    if not (path.is_file() or path.is_dir()):
        raise InputError(f"{option} {path}: is not a regular file or folder; choose another path")
    for source in inputs:
        if Path(source).exists() and os.path.samefile(path, source):
            raise InputError(f"{option} {path}: is an input of this command; inputs are never written over: "
                             "choose another path")
    if folder and path.is_file():
        raise InputError(f"{option} {path}: is a file; give a folder")
    if not folder and path.is_dir():
        raise InputError(f"{option} {path}: is a folder; give a file name")
    if ours is not None and not is_empty(path) and not ours(path):
        raise InputError(f"{option} {path}: exists and is not {what or 'an output'} this tool wrote; not "
                         "replacing it: remove it or choose another path")
    return path


@contextlib.contextmanager
def atomic_path(path: str | Path, *, create: bool = True) -> Iterator[Path]:
    """A temporary path beside ``path``; renamed onto ``path`` when the block ends without an error.

    ``create``: the temporary file exists (empty) when the block starts; False: its name is free
    (a name no other file has, for writers that refuse to overwrite), and the block must create it.

    Examples
    --------
    >>> import tempfile
    >>> folder = Path(tempfile.mkdtemp())
    >>> with atomic_path(folder / "out.txt") as tmp:
    ...     _ = tmp.write_text("whole")
    >>> (folder / "out.txt").read_text(), sorted(p.name for p in folder.iterdir())
    ('whole', ['out.txt'])
    >>> with atomic_path(folder / "out.txt", create=False) as tmp:
    ...     fresh = not tmp.exists()
    ...     _ = tmp.write_text("again")
    >>> fresh, (folder / "out.txt").read_text(), sorted(p.name for p in folder.iterdir())
    (True, 'again', ['out.txt'])
    """
    path = Path(path)
    fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp = Path(name)
    if not create:
        tmp.unlink()  # the name stays ours in practice: mkstemp's random part, in the target's folder
    try:
        yield tmp
        if path.exists() and not path.is_file():
            raise IsADirectoryError(21, "not a file", str(path))
        mode = 0o666 & ~_umask()
        os.chmod(tmp, mode)  # mkstemp makes it 0600; an output file gets the usual permissions
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


@contextlib.contextmanager
def atomic_directory(path: str | Path) -> Iterator[Path]:
    """A free path of the same name as ``path`` in a hidden folder beside it, moved onto ``path`` when
    the block ends without an error.

    The block's writer creates the folder (a ROS 2 bag: rosbags names the files inside after their
    folder, so it sees the final name). An existing ``path`` is moved aside into the hidden folder
    first and removed once the new folder is in place, so ``path`` holds the old folder or the whole
    new one, never a half-written one; a failed write leaves ``path`` as it was.

    Examples
    --------
    >>> import tempfile
    >>> folder = Path(tempfile.mkdtemp())
    >>> for text in ("old", "new"):
    ...     with atomic_directory(folder / "bag") as tmp:
    ...         tmp.mkdir()
    ...         _ = (tmp / "bag_0.mcap").write_text(text)
    >>> (folder / "bag" / "bag_0.mcap").read_text(), sorted(p.name for p in folder.iterdir())
    ('new', ['bag'])
    """
    path = Path(path)
    staging = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    try:
        new = staging / path.name
        yield new
        if path.exists() or path.is_symlink():
            os.replace(path, staging / ".replaced")  # aside, inside the folder removed below
        os.replace(new, path)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_bytes_atomic(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (see the module docstring); the path written."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def write_text_atomic(path: str | Path, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically (see the module docstring); the path written."""
    return write_bytes_atomic(path, text.encode(encoding))
