"""One way to open a dataset: each failure kind has one message, the same through every
entry (training, ``aerohrl.load_dataset``, ``datagen info``, the Gymnasium env)."""

import json
import shutil

import numpy as np
import pytest

import aerohrl
from aerohrl.datagen.dataset import (
    DatasetDamaged,
    DatasetError,
    DatasetMissing,
    NotAnAerohrlDataset,
    UnsupportedDatasetVersion,
    open_dataset,
)
from aerohrl.errors import UserError


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """A tiny `datagen build` (2 goals): its manifest has everything `datagen info` prints."""
    from aerohrl.datagen.build import build
    from aerohrl.datagen.spec import DatasetSpec

    return build(DatasetSpec(goals=2, seed=5), tmp_path_factory.mktemp("ds"), progress=False, log=lambda *a: None).path


def _missing(built, tmp_path):
    return tmp_path / "nope"


def _not_aerohrl(built, tmp_path):
    p = tmp_path / "plain-lerobot"
    shutil.copytree(built, p)
    (p / "meta" / "aerohrl.json").unlink()
    return p


def _damaged(built, tmp_path):
    p = tmp_path / "damaged"
    shutil.copytree(built, p)
    card = p / "README.md"
    card.write_bytes(card.read_bytes().replace(b"Expert", b"expert", 1))
    return p


def _unsupported(built, tmp_path):
    p = tmp_path / "old"
    shutil.copytree(built, p)
    info = json.loads((p / "meta" / "info.json").read_text())
    info["codebase_version"] = "v2.1"
    (p / "meta" / "info.json").write_text(json.dumps(info, indent=4))
    return p


KINDS = {
    "missing": (_missing, DatasetMissing, "no dataset at {p} (build one with `datagen build`)"),
    "not-aerohrl": (
        _not_aerohrl,
        NotAnAerohrlDataset,
        "{p} is not an aerohrl dataset (no meta/aerohrl.json); build one with `datagen build`",
    ),
    "damaged": (
        _damaged,
        DatasetDamaged,
        "dataset {p} is damaged: checksum mismatch: README.md; `datagen validate {p}` lists every problem",
    ),
    "unsupported": (
        _unsupported,
        UnsupportedDatasetVersion,
        "{p} is a LeRobot v2.1 dataset; aerohrl reads LeRobot v3.0 (rebuild it with `datagen build`)",
    ),
}


@pytest.fixture(params=sorted(KINDS))
def broken(request, built, tmp_path):
    make, kind, message = KINDS[request.param]
    p = make(built, tmp_path)
    return request.param, p, kind, message.format(p=p)


def test_open_dataset_raises_one_error_per_kind(broken):
    _, p, kind, message = broken
    with pytest.raises(kind) as e:
        open_dataset(p)
    assert str(e.value) == message
    assert isinstance(e.value, DatasetError) and isinstance(e.value, UserError) and isinstance(e.value, ValueError)


def test_api_load_dataset(broken):
    _, p, kind, message = broken
    for as_ in ("numpy", "torch"):
        with pytest.raises(kind) as e:
            aerohrl.load_dataset(p, as_=as_)
        assert str(e.value) == message, as_


def test_train_cli(broken, tmp_path, capsys):
    from aerohrl.algorithms import cli

    _, p, _, message = broken
    assert cli.main(["--algo", "gcsl", "--dataset", str(p), "--out", str(tmp_path / "runs"), "--quiet"]) == 2
    assert capsys.readouterr().err.strip() == f"train: error: {message}"


def test_datagen_info(broken, capsys):
    """A damaged dataset is shown with a warning (exit 0); the other kinds are errors."""
    from aerohrl.datagen.cli import main

    name, p, _, message = broken
    code = main(["info", str(p)])
    err = capsys.readouterr().err.strip()
    if name == "damaged":
        assert code == 0 and err == f"datagen: warning: {message}; what follows may be wrong"
    else:
        assert code == 2 and err == f"datagen: error: {message}"


def test_gym_env(broken):
    _, p, kind, message = broken
    with pytest.raises(kind) as e:
        aerohrl.make_env(dataset=p)
    assert str(e.value) == message


def test_other_folders(tmp_path, built):
    """An empty folder is not a dataset; a manifest of another format neither; an
    unreadable info.json is damage."""
    with pytest.raises(NotAnAerohrlDataset, match="no meta/aerohrl.json"):
        open_dataset(tmp_path)
    p = tmp_path / "d"
    shutil.copytree(built, p)
    (p / "meta" / "info.json").write_text("{not json")
    with pytest.raises(DatasetDamaged, match=r"^dataset .* is damaged: cannot read meta/info.json"):
        open_dataset(p, verify=False)


def test_handle(built):
    ds = open_dataset(built)
    assert ds.version == built.name and ds.spec["goals"] == 2 and ds.checksum and ds.problems() == []
    cols = ds.columns()
    some = ds.columns(["episode_index", "observation.desired_goal"])
    assert list(some) == ["episode_index", "observation.desired_goal"]
    np.testing.assert_array_equal(some["observation.desired_goal"], cols["observation.desired_goal"])
    with pytest.raises(UserError, match="no feature 'nothing'"):
        ds.columns(["nothing"])
