"""Atomic file output, checkpoint checksums and the clean-up of killed writes.

Every file the project writes (datasets' metadata, run configs, checkpoints, metrics
rewrites, evaluation results, figures, IPP lattices and models) goes through
:func:`atomic_path`: the bytes are written to a temporary name beside the target
(``.NAME.tmp-PID<suffix>``), flushed to disk, renamed over the target and the folder
is synced. A reader therefore sees the old file or the new one, never a part; a
killed writer leaves only its temporary, which :func:`remove_stale_temporaries`
deletes at the next start (its process is gone). Any ``OSError`` while writing (a full
disk, a read-only folder) becomes a one-line :class:`~aerohrl.errors.UserError`
naming the file; the target keeps its previous content.

Checkpoints (:func:`torch_save`) also get a sidecar ``NAME.sha256`` in ``sha256sum``
format, written before the checkpoint is renamed into place; :func:`torch_load`
verifies it on every load, so a flipped byte is an error instead of a changed weight.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import re
import shutil
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterator

from aerohrl.errors import UserError

CHECKSUM_SUFFIX = ".sha256"
_CHUNK = 1 << 20
# .NAME.tmp-PID with an optional extension kept for writers that infer the format from it
_TEMP = re.compile(r"^\..+\.tmp-(\d+)(\.[A-Za-z0-9]+)?$")


class CheckpointDamaged(UserError):
    """A checkpoint whose bytes differ from its recorded SHA-256, or that cannot be read."""


def temp_path(path: Path) -> Path:
    """The temporary name of ``path`` for this process (hidden, same folder, same extension)."""
    return path.with_name(f".{path.name}.tmp-{os.getpid()}{path.suffix}")


def write_error(path: str | os.PathLike[str], e: OSError) -> UserError:
    """The one-line error for a failed write of ``path``."""
    hint = (
        "; free some space and run it again (files written before are intact)" if e.errno in (errno.ENOSPC, errno.EDQUOT) else ""
    )
    return UserError(f"cannot write {path}: {e.strerror or e}{hint}")


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; when the block ends normally the file is
    synced and renamed over ``path``. On any exception the temporary is removed and
    ``path`` is untouched; an ``OSError`` is re-raised as a one-line UserError."""
    path = Path(path)
    tmp = temp_path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        yield tmp
        _fsync(tmp)
        os.replace(tmp, path)
        _fsync(path.parent)
    except OSError as e:
        raise write_error(path, e) from None
    finally:
        if tmp.exists():
            tmp.unlink(missing_ok=True)


def write_bytes(path: str | os.PathLike[str], data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (temporary, fsync, rename); returns ``path``."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)
    return Path(path)


def write_text(path: str | os.PathLike[str], text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; returns ``path``."""
    return write_bytes(path, text.encode())


def write_json(path: str | os.PathLike[str], obj: Any) -> Path:
    """Write ``obj`` as indented JSON with sorted keys to ``path`` atomically; returns ``path``."""
    return write_text(path, json.dumps(obj, indent=2, sort_keys=True) + "\n")


def save_figure(fig: Any, path: str | os.PathLike[str], **kw: Any) -> Path:
    """``fig.savefig`` through a temporary (the format follows ``path``'s extension, png without one)."""
    path = Path(path)
    kw.setdefault("format", path.suffix.lstrip(".") or "png")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, **kw)
    return path


def new_folder(path: str | os.PathLike[str]) -> bool:
    """Create ``path`` (and its parents) unless it exists; True when this call created it.
    The final ``mkdir`` is exclusive, so of two processes claiming one folder exactly one
    gets True: how run folders are made private to one run."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.mkdir()
    except FileExistsError:
        return False
    except OSError as e:
        raise write_error(path, e) from None
    return True


# ----------------------------------------------------------------------------- checksums


def sha256_file(path: str | os.PathLike[str]) -> str:
    """The hex SHA-256 digest of the file at ``path`` (read in chunks)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(_CHUNK):
            h.update(chunk)
    return h.hexdigest()


def checksum_path(path: str | os.PathLike[str]) -> Path:
    """The SHA-256 sidecar of ``path`` (``path`` + ``CHECKSUM_SUFFIX``)."""
    path = Path(path)
    return path.with_name(path.name + CHECKSUM_SUFFIX)


class _HashingWriter:
    """A write-only file object that hashes what passes and keeps the OSError it met:
    torch.save turns a failed write into a RuntimeError without errno."""

    def __init__(self, f):
        self.f, self.h, self.error = f, hashlib.sha256(), None

    def write(self, b) -> int:
        try:
            n = self.f.write(b)
        except OSError as e:
            self.error = e
            raise
        self.h.update(b)
        return n

    def flush(self) -> None:
        self.f.flush()


def torch_save(path: str | os.PathLike[str], obj: Any) -> str:
    """``torch.save`` atomically with a SHA-256 sidecar; returns the digest."""
    import torch

    path = Path(path)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            w = _HashingWriter(f)
            try:
                torch.save(obj, w)  # type: ignore[arg-type]  # torch's stub asks IO[bytes]; save needs only write()
            except RuntimeError:
                if w.error is not None:
                    raise w.error from None
                raise
        digest = w.h.hexdigest()
        write_text(checksum_path(path), f"{digest}  {path.name}\n")  # before the rename: a checkpoint in place has its hash
    return digest


def recorded_sha256(path: str | os.PathLike[str]) -> str | None:
    """The digest in ``path``'s sidecar; None when there is none (written before checksums)."""
    side = checksum_path(path)
    try:
        text = side.read_text()
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError) as e:
        raise CheckpointDamaged(f"cannot read {side}: {getattr(e, 'strerror', None) or e}") from None
    digest = text.split(maxsplit=1)[0] if text.strip() else ""
    if not re.fullmatch(r"[0-9a-f]{64}", digest):
        raise CheckpointDamaged(f"{side} is damaged (no SHA-256 in it)")
    return digest


def verify(path: str | os.PathLike[str]) -> bool:
    """True when ``path`` matches its sidecar, False when it has none; CheckpointDamaged
    (naming the file) on a mismatch, a missing file or an unreadable one."""
    path = Path(path)
    want = recorded_sha256(path)
    try:
        got = sha256_file(path)
    except FileNotFoundError:
        raise CheckpointDamaged(f"checkpoint {path} is missing") from None
    except OSError as e:
        raise CheckpointDamaged(f"cannot read checkpoint {path}: {e.strerror or e}") from None
    if want is None:
        return False
    if got != want:
        raise CheckpointDamaged(f"checkpoint {path} is damaged: its SHA-256 differs from {checksum_path(path).name}")
    return True


def torch_load(
    path: str | os.PathLike[str],
    *,
    map_location: Any = "cpu",
    weights_only: bool = False,
    warn: Callable[[str], Any] | None = None,
) -> Any:
    """Verify ``path`` against its sidecar, then ``torch.load`` it. A file without a
    sidecar (written before checksums) loads after ``warn(message)`` when given.
    CheckpointDamaged when the hash differs or torch cannot read the file."""
    import torch

    path = Path(path)
    if not verify(path) and warn is not None:
        warn(f"{path} has no {CHECKSUM_SUFFIX} file (written before checkpoints had checksums); loaded unverified")
    try:
        return torch.load(path, map_location=map_location, weights_only=weights_only)
    except Exception as e:  # torch raises many types on a truncated or foreign file
        raise CheckpointDamaged(
            f"checkpoint {path} is damaged: {type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"
        ) from None


def remove(path: str | os.PathLike[str]) -> None:
    """Delete a checkpoint and its sidecar."""
    path = Path(path)
    path.unlink(missing_ok=True)
    checksum_path(path).unlink(missing_ok=True)


# ----------------------------------------------------------------------------- killed writers


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's live process
        return True
    except OverflowError:
        return False
    return True


def temp_owner(name: str) -> int | None:
    """The pid in a temporary's name (``.NAME.tmp-PID[.ext]``); None for other names."""
    m = _TEMP.match(name)
    return int(m.group(1)) if m else None


def remove_stale_temporaries(folder: str | os.PathLike[str]) -> list[Path]:
    """Delete the temporaries in ``folder`` whose writer process is gone (a kill during a
    write); a live writer's are kept. Returns what was removed."""
    folder = Path(folder)
    removed: list[Path] = []
    if not folder.is_dir():
        return removed
    for p in folder.iterdir():
        pid = temp_owner(p.name)
        if pid is None or _alive(pid):
            continue
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)
        removed.append(p)
    return removed


__all__ = [
    "atomic_path",
    "write_bytes",
    "write_text",
    "write_json",
    "save_figure",
    "torch_save",
    "torch_load",
    "verify",
    "sha256_file",
    "checksum_path",
    "recorded_sha256",
    "remove",
    "remove_stale_temporaries",
    "temp_owner",
    "new_folder",
    "CheckpointDamaged",
    "write_error",
]
