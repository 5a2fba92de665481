"""aerohrl.atomic: atomic writes, a full disk, checkpoint checksums, killed writers' temporaries."""

import pytest
import torch

from aerohrl import atomic
from aerohrl.atomic import CheckpointDamaged
from aerohrl.errors import UserError


def test_write_replaces_whole_files_and_leaves_no_temporary(tmp_path):
    f = tmp_path / "sub" / "a.json"
    atomic.write_json(f, {"x": 1})
    atomic.write_json(f, {"x": 2})
    assert f.read_text() == '{\n  "x": 2\n}\n'
    assert [p.name for p in f.parent.iterdir()] == ["a.json"]


def test_a_failing_writer_keeps_the_old_file(tmp_path):
    f = tmp_path / "a.txt"
    atomic.write_text(f, "old")
    with pytest.raises(RuntimeError):
        with atomic.atomic_path(f) as tmp:
            tmp.write_text("half")
            raise RuntimeError("killed")
    assert f.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["a.txt"]


def test_full_disk_is_one_line_naming_the_file_and_keeps_the_old_content(small_disk):
    f = small_disk.path / "model.pt"
    atomic.torch_save(f, {"w": torch.zeros(10)})
    before = f.read_bytes()
    small_disk.fill()
    with pytest.raises(UserError) as e:
        atomic.torch_save(f, {"w": torch.ones(200_000)})  # 800 kB: does not fit
    msg = str(e.value)
    assert str(f) in msg and "No space left on device" in msg and "\n" not in msg
    assert f.read_bytes() == before and atomic.verify(f)
    assert not [p for p in small_disk.path.iterdir() if ".tmp-" in p.name]
    small_disk.free()
    atomic.torch_save(f, {"w": torch.ones(200_000)})
    assert atomic.verify(f)


def test_checkpoint_sidecar_catches_a_flipped_byte(tmp_path):
    f = tmp_path / "step-000000010.pt"
    digest = atomic.torch_save(f, {"w": torch.arange(1000.0)})
    assert atomic.checksum_path(f).read_text() == f"{digest}  {f.name}\n"  # sha256sum -c format
    assert atomic.torch_load(f)["w"][999] == 999.0
    raw = bytearray(f.read_bytes())
    raw[len(raw) // 2] ^= 0x01  # inside the tensor data: torch itself would load it
    f.write_bytes(bytes(raw))
    with pytest.raises(CheckpointDamaged, match=r"step-000000010\.pt is damaged: its SHA-256 differs") as e:
        atomic.torch_load(f)
    assert "\n" not in str(e.value)


def test_old_checkpoint_without_sidecar_loads_with_a_warning(tmp_path):
    f = tmp_path / "old.pt"
    torch.save({"w": torch.ones(3)}, f)
    said = []
    assert atomic.torch_load(f, warn=said.append)["w"].sum() == 3
    assert len(said) == 1 and "no .sha256 file" in said[0]
    f.write_bytes(f.read_bytes()[:50])  # truncated and unverifiable: torch's own error, as one line
    with pytest.raises(CheckpointDamaged, match="old.pt is damaged"):
        atomic.torch_load(f)


def test_stale_temporaries_of_dead_writers_are_removed(tmp_path, dead_pid):
    dead, alive = dead_pid, atomic.os.getpid()
    stale = tmp_path / f".step-000000040.pt.tmp-{dead}.pt"
    stale.write_bytes(b"partial")
    stale_dir = tmp_path / f".n10-s0-abc.tmp-{dead}"
    stale_dir.mkdir()
    live = tmp_path / f".metrics.jsonl.tmp-{alive}.jsonl"
    live.write_text("")
    keep = tmp_path / "step-000000020.pt"
    keep.write_bytes(b"x")
    removed = atomic.remove_stale_temporaries(tmp_path)
    assert sorted(removed) == sorted([stale, stale_dir])
    assert live.exists() and keep.exists()


def test_new_folder_is_exclusive(tmp_path):
    from concurrent.futures import ThreadPoolExecutor

    target = tmp_path / "runs" / "same-name"
    with ThreadPoolExecutor(8) as ex:
        won = list(ex.map(lambda _: atomic.new_folder(target), range(8)))
    assert won.count(True) == 1
