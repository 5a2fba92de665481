"""``meta/aerohrl.json``: our own metadata and the SHA-256 of every file of a dataset.

lerobot drops unknown ``info.json`` keys, so the build's metadata (generator version,
spec, seed, ranges, vehicle/controller parameters, outcomes, ...) lives in this separate
file, together with::

    "checksums":        {"<relative POSIX path>": "<sha256 hex>", ...}   every other file
    "manifest_sha256":  sha256 of the canonical JSON of the manifest without this field

The file's bytes must equal the canonical serialisation (sorted keys, 2-space indent,
UTF-8, ``repr`` floats, no NaN/inf, trailing newline), so whitespace edits are caught
too; with the self-hash, a flipped byte anywhere in the manifest itself is detected.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from aerohrl import atomic
from aerohrl.atomic import sha256_file
from aerohrl.errors import UserError

MANIFEST_PATH = "meta/aerohrl.json"
SELF_HASH_KEY = "manifest_sha256"
CHECKSUMS_KEY = "checksums"


def _jsonable(obj, where: str = "metadata"):
    """Plain JSON types from numpy scalars/arrays, tuples, paths; rejects NaN/inf."""
    if isinstance(obj, dict):
        out = {}
        for k, v in obj.items():
            if not isinstance(k, str):
                raise ValueError(f"{where}: key {k!r} is not a string")
            out[k] = _jsonable(v, f"{where}.{k}")
        return out
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v, f"{where}[{i}]") for i, v in enumerate(obj)]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist(), where)
    if isinstance(obj, np.generic):
        return _jsonable(obj.item(), where)
    if isinstance(obj, bool) or obj is None or isinstance(obj, str):
        return obj
    if isinstance(obj, int):
        return int(obj)
    if isinstance(obj, float):
        if not math.isfinite(obj):
            raise ValueError(f"{where}: non-finite number {obj!r} cannot be stored")
        return float(obj)
    if isinstance(obj, Path):
        return obj.as_posix()
    raise ValueError(f"{where}: {type(obj).__name__} is not JSON-serialisable")


def canonical_json(obj: Any) -> bytes:
    """The one serialisation of a manifest: sorted keys, indent 2, UTF-8, newline."""
    return (json.dumps(obj, sort_keys=True, indent=2, ensure_ascii=False, allow_nan=False) + "\n").encode("utf-8")


def _self_hash(manifest: dict) -> str:
    body = {k: v for k, v in manifest.items() if k != SELF_HASH_KEY}
    return hashlib.sha256(canonical_json(body)).hexdigest()


def _dataset_files(root: Path) -> list[str]:
    """Relative POSIX paths of every file under root (symlinks included), sorted."""
    out = []
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames.sort()
        for name in filenames:
            out.append((Path(dirpath) / name).relative_to(root).as_posix())
    return sorted(out)


def write_manifest(root: str | Path, metadata: dict, known: dict[str, str] | None = None) -> dict:
    """Write ``meta/aerohrl.json`` = ``metadata`` + checksums of every other file under
    ``root`` + the self-hash; return the manifest written. Call it last. ``known``: SHA-256
    digests already taken of files that have not changed since (relative POSIX paths, as
    the data files a writer hashed when it closed them); the other files are read here."""
    known = known or {}
    root = Path(root)
    if not isinstance(metadata, dict):
        raise ValueError("metadata must be a dict")
    for k in (CHECKSUMS_KEY, SELF_HASH_KEY):
        if k in metadata:
            raise ValueError(f"metadata must not contain the reserved key {k!r}")
    manifest = _jsonable(metadata)
    manifest[CHECKSUMS_KEY] = {
        rel: known[rel] if rel in known else sha256_file(root / rel) for rel in _dataset_files(root) if rel != MANIFEST_PATH
    }
    manifest[SELF_HASH_KEY] = _self_hash(manifest)
    atomic.write_bytes(root / MANIFEST_PATH, canonical_json(manifest))
    return manifest


def load_manifest(root: Path) -> tuple[dict | None, list[str]]:
    """(manifest, problems of the manifest itself): None when it is missing or cannot be
    parsed; problems when its bytes are not canonical or its self-hash does not match."""
    path = root / MANIFEST_PATH
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        return None, [f"{MANIFEST_PATH} is missing (not an aerohrl dataset?)"]
    except OSError as e:
        return None, [f"cannot read {MANIFEST_PATH}: {e.strerror or e}"]
    try:
        m = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        return None, [f"{MANIFEST_PATH} is corrupt: {e}"]
    if not isinstance(m, dict) or not isinstance(m.get(CHECKSUMS_KEY), dict) or not isinstance(m.get(SELF_HASH_KEY), str):
        return None, [f"{MANIFEST_PATH} is corrupt: no checksums or {SELF_HASH_KEY}"]
    problems = []
    try:
        if canonical_json(m) != raw:
            problems.append(f"{MANIFEST_PATH} is corrupt: its bytes are not the canonical serialisation")
    except ValueError as e:
        problems.append(f"{MANIFEST_PATH} is corrupt: {e}")
    try:
        if _self_hash(m) != m[SELF_HASH_KEY]:
            problems.append(f"{MANIFEST_PATH} is corrupt: {SELF_HASH_KEY} does not match its content")
    except ValueError as e:
        problems.append(f"{MANIFEST_PATH} is corrupt: {e}")
    return m, problems


def read_manifest(root: str | Path) -> dict:
    """The manifest of the dataset at ``root``; UserError if missing or corrupt."""
    root = Path(root)
    m, problems = load_manifest(root)
    if problems:
        raise UserError(f"{root}: {problems[0]}")
    assert m is not None  # load_manifest returns None only with a problem
    return m


def validate(root: str | Path) -> list[str]:
    """Every integrity problem of the dataset at ``root`` (empty list: intact): the
    manifest itself, each file's SHA-256, missing and unexpected files, and the LeRobot
    structure (:func:`aerohrl.datagen.lerobot_validate.check_structure`)."""
    from aerohrl.datagen.lerobot_validate import check_structure

    root = Path(root)
    if not root.is_dir():
        return [f"no dataset directory at {root}"]
    m, problems = load_manifest(root)
    if m is not None:
        listed = m[CHECKSUMS_KEY]
        present = set(_dataset_files(root)) - {MANIFEST_PATH}
        for rel in sorted(listed):
            if rel not in present:
                problems.append(f"missing file {rel}")
                continue
            try:
                digest = sha256_file(root / rel)
            except OSError as e:
                problems.append(f"cannot read {rel}: {e.strerror or e}")
                continue
            if digest != listed[rel]:
                problems.append(f"checksum mismatch: {rel}")
        for rel in sorted(present - set(listed)):
            problems.append(f"unexpected file {rel}")
    problems += check_structure(root)
    return problems


__all__ = ["MANIFEST_PATH", "write_manifest", "read_manifest", "load_manifest", "validate", "canonical_json", "sha256_file"]
