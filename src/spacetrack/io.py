"""Atomic file and folder writes: a reader never sees a half-written file, dataset or cache."""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path


def _plain_mode(base: int) -> int:
    """`base` (0o666 for files, 0o777 for folders) less the umask: what open() or mkdir() would give."""
    umask = os.umask(0)
    os.umask(umask)
    return base & ~umask


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary sibling of `path` to write to; it replaces `path` only if the block succeeds.

    The parent folder must exist (a missing output folder is the caller's error, not created here).
    """
    path = Path(path)
    if not path.parent.is_dir():
        raise FileNotFoundError(f"output folder {path.parent} does not exist (writing {path.name})")
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    # mkstemp makes the file private (0600); give it the permissions a plain open() would
    os.chmod(tmp, _plain_mode(0o666))
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def atomic_write_text(path: str | Path, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text)


@contextmanager
def atomic_dir(path: str | Path, *, overwrite: bool = False) -> Iterator[Path]:
    """Yield an empty temporary folder beside `path`; it is renamed to `path` only when the block succeeds.

    With `overwrite`, an existing `path` is replaced (the old one is removed after the swap); without it,
    an existing `path` is an error raised before any work is done. On failure the temporary folder is
    removed and `path` is left as it was.
    """
    path = Path(path)
    if not path.parent.is_dir():
        raise FileNotFoundError(f"output folder {path.parent} does not exist (building {path.name})")
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} already exists; pass overwrite=true to replace it")
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.tmp-", dir=path.parent))
    os.chmod(tmp, _plain_mode(0o777))
    try:
        yield tmp
        if path.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{path.name}.old-", dir=path.parent))
            os.replace(path, old / path.name)
            os.replace(tmp, path)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, path)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def file_hash(path: str | Path) -> str:
    """`sha256:<first 16 hex digits>` of a file's bytes: names a weights file whatever its path."""
    digest = hashlib.sha256(Path(path).read_bytes()).hexdigest()
    return f"sha256:{digest[:16]}"


def files_hash(paths: Iterable[str | Path]) -> str:
    """`sha256:<first 16 hex digits>` of the names and bytes of `paths` in order (each file read in 1 MiB
    blocks): what a sequence of frames, or a set of truth files, holds, whatever folder it lies in. A file
    that does not exist adds its name and a marker, so that creating it changes the hash."""
    digest = hashlib.sha256()
    for path in paths:
        path = Path(path)
        if not path.is_file():
            digest.update(f"{path.name}\0missing\0".encode())
            continue
        digest.update(f"{path.name}\0{path.stat().st_size}\0".encode())
        with path.open("rb") as handle:
            while block := handle.read(1 << 20):
                digest.update(block)
    return f"sha256:{digest.hexdigest()[:16]}"


def load_torch_file(path: str | Path, what: str, *, mmap: bool = False) -> object:
    """The object saved by `torch.save` at `path` (tensors only, on the CPU), with a clear error naming the
    file when it is missing or unreadable; `what` says what the file should be ("checkpoint", ...).
    `mmap`: map the file instead of reading it, so only the entries touched are read."""
    import torch  # only the model code needs torch; keep this module light for the data tools

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what} {path} not found")
    try:
        return torch.load(path, map_location="cpu", weights_only=True, mmap=mmap)
    except Exception as err:
        raise ValueError(f"{path} is not a readable {what}: {err}") from err
