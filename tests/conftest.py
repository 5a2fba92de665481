"""Shared pytest set-up.

The Hugging Face Hub is made unreachable for the whole suite: lerobot silently falls
back to the Hub when a local dataset is missing or inconsistent, and a test must fail
loudly then instead of passing by download (or hanging).

``small_disk`` is a folder on a file system that is nearly full: a real 2 MB tmpfs
where the tests run as root and may mount one, else a folder whose writes fail with
ENOSPC once ``fill()`` is called (a monkeypatched ``os.write`` path would miss torch's
own writer, so the fallback patches the file object ``open`` returns).

``fingerprint(x)`` and ``assert_fingerprint(x, ref)`` pin a float array across machines:
numpy's SIMD paths (AVX2, AVX-512, NEON) round transcendental functions differently in
the last bit, so a reference taken as bytes holds only on the CPU it was taken on.

``load_experiment(NAME)`` imports the script ``experiments/NAME.py`` (not a package:
the scripts run as ``python experiments/NAME.py``) as a module, for tests that call
its functions.
"""

import errno
import importlib.util
import os
import subprocess
import sys
import uuid
from pathlib import Path

import pytest

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("HF_DATASETS_OFFLINE", "1")
os.environ.setdefault("MPLBACKEND", "Agg")

EXPERIMENTS = Path(__file__).resolve().parent.parent / "experiments"
sys.path.insert(0, str(EXPERIMENTS))  # the scripts import their shared study_tools as `python experiments/X.py` would


def load_experiment(name: str):
    """The script ``experiments/NAME.py`` imported as the module ``experiments_NAME``."""
    key = f"experiments_{name}"
    if key not in sys.modules:
        spec = importlib.util.spec_from_file_location(key, EXPERIMENTS / f"{name}.py")
        mod = importlib.util.module_from_spec(spec)
        sys.modules[key] = mod  # before running it: dataclasses look their module up
        spec.loader.exec_module(mod)
    return sys.modules[key]


# A run small enough to train in a test: the experiment scripts' tests read its checkpoint
TINY_TRAIN = dict(
    hidden=(16, 16), critic_hidden=(16, 16), batch_size=32, steps=20, log_every=10, checkpoint_every=20, eval_every=0
)


def train_tiny(run_dir: Path, dataset: Path, **settings) -> Path:
    """A :data:`TINY_TRAIN` cpu-preset run on ``dataset`` (``settings`` on top), trained to its end."""
    import torch

    from aerohrl.algorithms.config import make_config
    from aerohrl.algorithms.trainer import start_run

    torch.set_num_threads(1)
    start_run(make_config("cpu", dataset=str(dataset), **{**TINY_TRAIN, **settings}), run_dir, progress=False).train()
    return run_dir


FINGERPRINT_RTOL = 1e-9  # of the array's L1 norm: far above round-off, far below any change of the arithmetic


def fingerprint(x) -> list[float]:
    """Four fixed random projections of the flattened array ``x``, then its L1 norm: a
    reference of a large array that a test can keep inline."""
    import numpy as np

    x = np.asarray(x, dtype=np.float64).ravel()
    w = np.random.default_rng(0).standard_normal((4, x.size))
    return [float(v) for v in w @ x] + [float(np.abs(x).sum())]


def assert_fingerprint(x, ref, what: str = "array") -> None:
    """``x`` equals the array whose :func:`fingerprint` is ``ref``, to round-off: each
    projection within ``FINGERPRINT_RTOL`` of the L1 norm."""
    got = fingerprint(x)
    tol = FINGERPRINT_RTOL * max(ref[-1], 1e-300)
    bad = [i for i, (g, r) in enumerate(zip(got, ref)) if abs(g - r) > tol]
    assert len(got) == len(ref) and not bad, f"{what} moved from its reference: fingerprint {got}, reference {ref}"


class SmallDisk:
    """A folder whose file system can be filled up (``fill``) and freed (``free``)."""

    def __init__(self, path: Path, real: bool, monkeypatch):
        self.path, self.real, self._mp = path, real, monkeypatch
        self._filler = path / f".filler-{uuid.uuid4().hex}"

    def fill(self, leave: int = 0) -> None:
        """Use up the space, leaving about ``leave`` bytes free."""
        if self.real:
            with open(self._filler, "wb", buffering=0) as f:
                try:
                    while True:
                        f.write(b"\0" * 65536)
                except OSError as e:
                    assert e.errno == errno.ENOSPC
            if leave:
                size = self._filler.stat().st_size
                os.truncate(self._filler, max(0, size - leave))
            return
        import builtins

        real_open, root, budget = builtins.open, str(self.path), [leave]

        class Full:
            def __init__(self, f):
                self._f = f

            def write(self, b):
                budget[0] -= len(b)
                if budget[0] < 0:
                    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
                return self._f.write(b)

            def __getattr__(self, k):
                return getattr(self._f, k)

            def __enter__(self):
                return self

            def __exit__(self, *a):
                return self._f.__exit__(*a)

        def fake_open(file, mode="r", *a, **k):
            f = real_open(file, mode, *a, **k)
            return Full(f) if str(file).startswith(root) and any(c in mode for c in "wa") else f

        self._mp.setattr(builtins, "open", fake_open)

    def free(self) -> None:
        if self.real:
            self._filler.unlink(missing_ok=True)
        else:
            self._mp.undo()


@pytest.fixture
def dead_pid() -> int:
    """The pid of a process that has exited (what a killed writer leaves in its temporaries' names)."""
    p = subprocess.Popen(["true"])
    p.wait()
    return p.pid


@pytest.fixture
def small_disk(tmp_path, monkeypatch):
    mnt = tmp_path / "small-disk"
    mnt.mkdir()
    real = (
        os.geteuid() == 0
        and subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(mnt)], capture_output=True).returncode == 0
    )
    try:
        yield SmallDisk(mnt, real, monkeypatch)
    finally:
        if real:
            subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


@pytest.fixture(scope="module")
def dataset_dir(tmp_path_factory):
    """A small synthetic dataset (algorithms/synthetic.py), one per test module."""
    from aerohrl.algorithms.synthetic import write_synthetic_dataset

    return write_synthetic_dataset(tmp_path_factory.mktemp("ds") / "synthetic" / "v1")


@pytest.fixture(scope="module")
def data(dataset_dir):
    """That dataset, loaded for training."""
    from aerohrl.algorithms.data import load_dataset

    return load_dataset(dataset_dir)
