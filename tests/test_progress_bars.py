"""Progress bars only on terminals: asked for, they still stay out of a log file or pipe."""

from aerohrl.datagen.build import build
from aerohrl.datagen.spec import DatasetSpec


def test_progress_bars_stay_out_of_non_terminal_output(tmp_path, capsys):
    build(DatasetSpec(goals=3, seed=9), tmp_path, progress=True, log=lambda m: None)
    out = capsys.readouterr()
    assert "expert rollouts" not in out.err + out.out and "\r" not in out.err + out.out
