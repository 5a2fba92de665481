"""LeRobot loads our datasets quietly: no video backend is touched.

lerobot 0.6's ``LeRobotDataset.__init__`` calls ``get_safe_default_video_backend()`` whenever
no ``video_backend`` is given, video features or not; that imports torchcodec, which on a
machine without FFmpeg logs ~108 lines of library-loading traceback. The fixes are at the
source: the ``[lerobot]`` extra installs lerobot's dataset dependencies without torchcodec
(a bare call then logs one fallback line), and our loader and dataset card name the
backend (nothing is logged, nothing decoded: there is no video)."""

import os
import subprocess
import sys

import pytest

pytest.importorskip("lerobot")

from aerohrl.datagen.build import build  # noqa: E402
from aerohrl.datagen.spec import DatasetSpec  # noqa: E402


@pytest.fixture(scope="module")
def ds(tmp_path_factory):
    return build(DatasetSpec(goals=5, seed=4), tmp_path_factory.mktemp("lq"), progress=False, log=lambda m: None).path


def _load(code: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1"}
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)


@pytest.mark.slow  # three subprocesses that import lerobot (~45 s)
def test_lerobot_load_prints_no_traceback(ds):
    bare = _load(
        f"from lerobot.datasets.lerobot_dataset import LeRobotDataset\n"
        f"ds = LeRobotDataset('aerohrl/quadrotor-reach', root={str(ds)!r})\nprint(len(ds), ds[3]['action'].shape)"
    )
    assert bare.returncode == 0, bare.stderr[-2000:]
    assert "Traceback" not in bare.stderr and "libtorchcodec" not in bare.stderr, bare.stderr[:3000]
    assert len(bare.stderr.splitlines()) <= 1, bare.stderr  # at most lerobot's "falling back to 'pyav'" line
    named = _load(
        f"from lerobot.datasets.lerobot_dataset import LeRobotDataset\n"
        f"ds = LeRobotDataset('aerohrl/quadrotor-reach', root={str(ds)!r}, video_backend='pyav')\nprint(len(ds))"
    )
    assert named.returncode == 0 and named.stderr == "", named.stderr[:3000]
    ours = _load(
        f"import aerohrl\nds = aerohrl.load_dataset({str(ds)!r}, as_='lerobot')\nprint(len(ds), ds[0]['observation.state'].shape)"
    )
    assert ours.returncode == 0 and ours.stderr == "", ours.stderr[:3000]
    assert ours.stdout.split()[0] == bare.stdout.split()[0] == named.stdout.strip()


def test_card_tells_how_to_load_quietly_and_has_shapes(ds):
    card = (ds / "README.md").read_text()
    assert 'video_backend="pyav"' in card
    assert "| `observation.state` | float32 | (18,) |" in card and "| `action` | float32 | (4,) |" in card
    assert "| `observation.desired_goal` | float32 | (15,) |" in card and "| `next.success` | bool | (1,) |" in card
