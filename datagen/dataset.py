"""Opening a built dataset: the one checked entry point that every reader goes through.

``open_dataset(path)`` checks a dataset folder (``datagen build``'s
``datasets/<name>/<version>/``) and returns a :class:`DatasetHandle` with its metadata,
spec, version and column access. Training, ``aerohrl.load_dataset``, the ``datagen``
commands, the Gymnasium env, the exports and the sweep all open datasets with it, so a
failure reads the same everywhere. It raises one :class:`DatasetError` (a
:class:`aerohrl.errors.UserError` and a ``ValueError``) per failure kind:

* :class:`DatasetMissing`: ``no dataset at PATH (build one with `datagen build`)``
* :class:`NotAnAerohrlDataset`: ``PATH is not an aerohrl dataset (WHY); build one with
  `datagen build```, WHY naming what is missing (``no meta/aerohrl.json``)
* :class:`UnsupportedDatasetVersion`: ``PATH is a LeRobot VERSION dataset; aerohrl reads
  LeRobot v3.0 (rebuild it with `datagen build`)``
* :class:`DatasetDamaged`: ``dataset PATH is damaged: PROBLEM (+N more); `datagen validate
  PATH` lists every problem``

Every open reads and checks ``meta/aerohrl.json`` and ``meta/info.json`` (a damaged one
raises :class:`DatasetDamaged`); ``verify=True`` also checks every file's SHA-256 and
the LeRobot structure (about a second per 2 M frames), which
:meth:`DatasetHandle.verify` does later for a handle opened without it.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Iterable

import numpy as np

from aerohrl.datagen import manifest as _manifest
from aerohrl.datagen.lerobot_layout import CODEBASE_VERSION, INFO_PATH, DatasetLayout
from aerohrl.errors import UserError

FORMAT = "aerohrl-dataset"  # meta/aerohrl.json "format" of every dataset datagen writes


class DatasetError(UserError, ValueError):
    """A dataset folder that cannot be opened: reported in one line by the commands."""


class DatasetMissing(DatasetError):
    """No folder at the path given."""

    def __init__(self, root: Path) -> None:
        super().__init__(f"no dataset at {root} (build one with `datagen build`)")


class NotAnAerohrlDataset(DatasetError):
    """A folder without our ``meta/aerohrl.json`` (not written by ``datagen build``)."""

    def __init__(self, root: Path, why: str) -> None:
        super().__init__(f"{root} is not an aerohrl dataset ({why}); build one with `datagen build`")


class DatasetDamaged(DatasetError):
    """A file fails its checksum, is missing or unexpected, or cannot be read;
    ``problems`` lists what was found."""

    def __init__(self, root: Path, problems: list[str]) -> None:
        self.problems = list(problems)
        more = f" (+{len(problems) - 1} more)" if len(problems) > 1 else ""
        super().__init__(f"dataset {root} is damaged: {problems[0]}{more}; `datagen validate {root}` lists every problem")


class UnsupportedDatasetVersion(DatasetError):
    """A dataset in another LeRobot format version than the one this code reads and writes."""

    def __init__(self, root: Path, version: object) -> None:
        super().__init__(
            f"{root} is a LeRobot {version} dataset; aerohrl reads LeRobot {CODEBASE_VERSION} (rebuild it with `datagen build`)"
        )


class DatasetHandle:
    """An opened dataset folder: its metadata (``meta/aerohrl.json``), LeRobot
    ``meta/info.json`` and columns. Made by :func:`open_dataset`."""

    def __init__(self, path: Path, manifest: dict, info: dict) -> None:
        self.path = path
        self.manifest = manifest
        self.info = info
        self.layout = DatasetLayout(path)

    @property
    def version(self) -> str | None:
        """The version name (``n250-s0-<hash8>``)."""
        return self.manifest.get("version")

    @property
    def name(self) -> str | None:
        """The dataset name (``quadrotor-reach``)."""
        return self.manifest.get("name")

    @property
    def spec(self) -> dict:
        """The spec the dataset was built from (``DatasetSpec.to_dict()``), or {}."""
        return self.manifest.get("spec") or {}

    @property
    def world(self) -> str:
        """The world the flights are in: ``free`` or ``maze-<name>`` (``spec["world"]``; a spec
        leaves it out at its default, free space)."""
        return self.spec.get("world", "free")

    @property
    def maze(self) -> dict | None:
        """A maze dataset's layout and frozen tasks (:meth:`aerohrl.worlds.maze.Maze.to_dict`), else None."""
        return self.manifest.get("maze")

    @property
    def checksum(self) -> str | None:
        """The manifest's self-hash: one SHA-256 that changes with any file."""
        return self.manifest.get(_manifest.SELF_HASH_KEY)

    @property
    def features(self) -> dict:
        """The LeRobot features (``{name: {"dtype", "shape", "names"}}``)."""
        return self.info["features"]

    def problems(self) -> list[str]:
        """Every integrity problem (each file's SHA-256, missing and unexpected files,
        the LeRobot structure); empty when intact."""
        return _manifest.validate(self.path)

    def verify(self) -> None:
        """Raise :class:`DatasetDamaged` when :meth:`problems` finds any."""
        problems = self.problems()
        if problems:
            raise DatasetDamaged(self.path, problems)

    def columns(self, features: Iterable[str] | None = None) -> dict[str, np.ndarray]:
        """Every feature (or those named) as numpy arrays, as
        :func:`aerohrl.datagen.lerobot_reader.read_columns`; an unreadable file raises
        :class:`DatasetDamaged`."""
        from aerohrl.datagen.lerobot_reader import read_columns

        names = None if features is None else list(features)
        if names is not None and (unknown := [k for k in names if k not in self.features]):
            raise UserError(f"dataset {self.path} has no feature {unknown[0]!r}")
        try:
            return read_columns(self.path, names)
        except DatasetError:
            raise
        except UserError as e:
            raise DatasetDamaged(self.path, [str(e)]) from None

    def __repr__(self) -> str:
        return f"DatasetHandle({str(self.path)!r}, version={self.version!r})"


def open_dataset(path: str | Path, *, verify: bool = True) -> DatasetHandle:
    """Open the dataset folder at ``path``, checked; the one way every reader opens one.

    Args:
        path: a dataset folder (``datasets/<name>/<version>``).
        verify: also check every file's SHA-256 against the manifest and the LeRobot
            structure (about a second per 2 M frames). Without it, only the manifest and
            ``meta/info.json`` are read and checked.

    Returns:
        A :class:`DatasetHandle`.

    Raises:
        DatasetMissing: no folder at ``path``.
        NotAnAerohrlDataset: no ``meta/aerohrl.json`` of an aerohrl dataset in it.
        DatasetDamaged: the manifest or ``meta/info.json`` is unreadable or corrupt, or
            (``verify``) any file fails its checksum or the LeRobot structure is broken.
        UnsupportedDatasetVersion: ``meta/info.json`` names another LeRobot format version.
    """
    root = Path(path)
    if not root.is_dir():
        raise DatasetMissing(root)
    if not (root / _manifest.MANIFEST_PATH).is_file():
        raise NotAnAerohrlDataset(root, f"no {_manifest.MANIFEST_PATH}")
    m, problems = _manifest.load_manifest(root)
    if m is None or problems:
        raise DatasetDamaged(root, problems)
    if m.get("format") != FORMAT:
        raise NotAnAerohrlDataset(root, f"{_manifest.MANIFEST_PATH} has format {m.get('format')!r}, not {FORMAT!r}")
    try:
        info = json.loads((root / INFO_PATH).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DatasetDamaged(root, [f"missing file {INFO_PATH}"]) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise DatasetDamaged(root, [f"cannot read {INFO_PATH}: {e}"]) from None
    if not isinstance(info, dict):
        raise DatasetDamaged(root, [f"{INFO_PATH} is not a JSON object"])
    if info.get("codebase_version") != CODEBASE_VERSION:
        raise UnsupportedDatasetVersion(root, info.get("codebase_version"))
    from aerohrl.datagen.lerobot_reader import read_info

    try:
        info = read_info(root)
    except UserError as e:
        raise DatasetDamaged(root, [str(e)]) from None
    ds = DatasetHandle(root, m, info)
    if verify:
        ds.verify()
    return ds


__all__ = [
    "open_dataset",
    "DatasetHandle",
    "DatasetError",
    "DatasetMissing",
    "NotAnAerohrlDataset",
    "DatasetDamaged",
    "UnsupportedDatasetVersion",
    "FORMAT",
]
