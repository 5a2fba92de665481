"""meta/aerohrl.json: metadata + SHA-256 of every file; any damaged, missing or extra file is caught."""

import json

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from aerohrl.datagen.lerobot_writer import write_dataset
from aerohrl.datagen.manifest import MANIFEST_PATH, canonical_json, read_manifest, validate, write_manifest
from aerohrl.errors import UserError

META = {
    "name": "quadrotor-reach",
    "generator": {"generator_version": "1", "aerohrl_version": "0.1.0"},
    "spec": {"goals": 3, "seed": 7, "pos_range": (1.0, 2.0), "a_max": np.float64(5.0)},
    "episodes": np.int64(3),
    "expert_success_rate": 2 / 3,
    "resampled_goals": 0,
    "vehicle": {"name": "hummingbird", "mass": np.float32(0.5), "inertia": np.diag([1e-3, 1e-3, 2e-3])},
    "note": "ünïcode ok",
}


def _dataset(root):
    rng = np.random.default_rng(0)
    lengths = np.array([5, 8, 6])
    F = int(lengths.sum())
    ep = np.repeat(np.arange(3), lengths)
    cols = {
        "observation.state": rng.standard_normal((F, 18), dtype=np.float32),
        "action": rng.standard_normal((F, 4), dtype=np.float32),
        "next.reward": rng.random(F, dtype=np.float32),
        "next.done": np.r_[ep[1:] != ep[:-1], True],
    }
    write_dataset(root, cols, ep, names={})
    # the build's extra files: dataset card and per-episode table
    (root / "README.md").write_text("# card\n")
    pq.write_table(pa.table({"goal": [1.0, 2.0, 3.0]}), root / "meta/aerohrl_episodes.parquet")


@pytest.fixture(scope="module")
def ds(tmp_path_factory):
    root = tmp_path_factory.mktemp("m") / "ds"
    _dataset(root)
    manifest = write_manifest(root, META)
    return root, manifest


def _files(root):
    return sorted(p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file())


def test_manifest_content_and_fresh_dataset_validates(ds):
    root, manifest = ds
    assert validate(root) == []
    m = read_manifest(root)
    assert m == manifest
    assert set(m["checksums"]) == set(_files(root)) - {MANIFEST_PATH}
    assert {"README.md", "meta/aerohrl_episodes.parquet", "meta/info.json", "data/chunk-000/file-000.parquet"} <= set(
        m["checksums"]
    )
    assert m["spec"]["pos_range"] == [1.0, 2.0] and m["episodes"] == 3 and m["vehicle"]["mass"] == 0.5
    assert m["vehicle"]["inertia"][2] == [0.0, 0.0, 0.002] and m["expert_success_rate"] == 2 / 3
    assert m["note"] == "ünïcode ok"
    raw = (root / MANIFEST_PATH).read_bytes()
    assert raw == canonical_json(m) and raw.endswith(b"\n")
    assert len(m["manifest_sha256"]) == 64


def test_writing_twice_gives_identical_bytes(ds, tmp_path):
    root, _ = ds
    a = (root / MANIFEST_PATH).read_bytes()
    write_manifest(root, META)
    assert (root / MANIFEST_PATH).read_bytes() == a


def test_a_flipped_byte_in_any_file_is_reported(ds):
    root, _ = ds
    files = _files(root)
    assert MANIFEST_PATH in files and len(files) >= 7
    for rel in files:
        p = root / rel
        raw = p.read_bytes()
        for pos in (0, len(raw) // 2, len(raw) - 1):
            bad = bytearray(raw)
            bad[pos] ^= 0x01
            p.write_bytes(bytes(bad))
            try:
                problems = validate(root)
            finally:
                p.write_bytes(raw)
            assert problems, f"flipped byte {pos} of {rel} went unnoticed"
            if rel == MANIFEST_PATH:
                assert any("aerohrl.json" in x for x in problems), problems
            else:
                assert f"checksum mismatch: {rel}" in problems, problems
    assert validate(root) == []


def test_missing_and_unexpected_files_are_reported(ds):
    root, _ = ds
    card = root / "README.md"
    raw = card.read_bytes()
    card.unlink()
    try:
        assert "missing file README.md" in validate(root)
    finally:
        card.write_bytes(raw)
    extra = root / "data/chunk-000/extra.bin"
    extra.write_bytes(b"x")
    try:
        problems = validate(root)
        assert "unexpected file data/chunk-000/extra.bin" in problems
    finally:
        extra.unlink()
    (root / "notes.txt").write_text("hi")
    try:
        assert validate(root) == ["unexpected file notes.txt"]
    finally:
        (root / "notes.txt").unlink()
    data = root / "data/chunk-000/file-000.parquet"
    raw = data.read_bytes()
    data.unlink()
    try:
        problems = validate(root)
        assert "missing file data/chunk-000/file-000.parquet" in problems and len(problems) > 1  # structure too
    finally:
        data.write_bytes(raw)
    assert validate(root) == []


def test_read_manifest_refuses_missing_or_corrupt(ds, tmp_path):
    root, _ = ds
    with pytest.raises(UserError, match="missing"):
        read_manifest(tmp_path)
    p = root / MANIFEST_PATH
    raw = p.read_bytes()
    try:
        p.write_bytes(b"{not json")
        with pytest.raises(UserError, match="corrupt"):
            read_manifest(root)
        m = json.loads(raw)
        m["seed"] = 8  # valid JSON, canonical form, but the self-hash no longer matches
        p.write_bytes(canonical_json(m))
        with pytest.raises(UserError, match="manifest_sha256"):
            read_manifest(root)
        assert any("manifest_sha256" in x for x in validate(root))
        p.write_bytes(raw.replace(b"\n", b"\r\n"))  # same content, other bytes
        with pytest.raises(UserError, match="canonical"):
            read_manifest(root)
        p.write_bytes(b"[]")
        with pytest.raises(UserError, match="corrupt"):
            read_manifest(root)
    finally:
        p.write_bytes(raw)
    assert validate(root) == []


def test_bad_metadata_is_refused(ds):
    root, _ = ds
    with pytest.raises(ValueError, match="reserved"):
        write_manifest(root, {"checksums": {}})
    with pytest.raises(ValueError, match="non-finite"):
        write_manifest(root, {"x": {"y": float("nan")}})
    with pytest.raises(ValueError, match="serialisable"):
        write_manifest(root, {"x": object()})
    assert validate(root) == []  # the failed writes left the manifest alone


def test_validate_on_a_non_dataset(tmp_path):
    assert validate(tmp_path / "nope")
    problems = validate(tmp_path)
    assert any("aerohrl.json" in p for p in problems) and any("info.json" in p for p in problems)
