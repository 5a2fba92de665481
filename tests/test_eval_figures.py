"""Figures: learning curves of seeds as a mean with a band; in trajectory plots
each goal has the colour of its flight."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes

from aerohrl.eval import plots


def _run(root: Path, seed: int, curve: list[tuple[int, float]]) -> Path:
    rd = root / f"gcsl-s{seed}"
    rd.mkdir(parents=True)
    (rd / "config.json").write_text(
        json.dumps({"config": {"algo": "gcsl", "preset": "cpu", "seed": seed, "steps": 300}, "dataset": {"version": "n250-s0-x"}})
    )
    (rd / "metrics.jsonl").write_text("".join(json.dumps({"step": s, "eval/reach_desired/success": v}) + "\n" for s, v in curve))
    return rd


def test_seed_band_is_mean_min_max_at_shared_steps():
    st, mean, lo, hi = plots._seed_band([[(100, 0.2), (200, 0.5)], [(100, 0.4), (200, 0.9), (300, 1.0)]])
    assert st.tolist() == [100, 200]
    np.testing.assert_allclose(mean, [0.3, 0.7]) and np.testing.assert_allclose(lo, [0.2, 0.5])
    np.testing.assert_allclose(hi, [0.4, 0.9])


def test_learning_curves_draw_one_band_per_experiment(tmp_path, monkeypatch):
    runs = [_run(tmp_path, s, [(100, 0.1 * s), (200, 0.2 + 0.1 * s)]) for s in range(3)]
    other = _run(tmp_path / "b", 0, [(100, 0.5), (200, 0.6)])
    cfg = json.loads((other / "config.json").read_text())
    cfg["config"]["algo"] = "td3bc"
    (other / "config.json").write_text(json.dumps(cfg))
    bands, lines = [], []
    real_fill, real_plot = Axes.fill_between, Axes.plot
    monkeypatch.setattr(
        Axes,
        "fill_between",
        lambda self, x, y1, y2, **kw: bands.append((list(x), list(y1), list(y2))) or real_fill(self, x, y1, y2, **kw),
    )
    monkeypatch.setattr(Axes, "plot", lambda self, *a, **kw: lines.append(kw.get("label")) or real_plot(self, *a, **kw))
    out = plots.plot_learning_curves([*runs, other], tmp_path / "c.png")
    assert out.stat().st_size > 5000
    assert bands == [([100, 200], [0.0, 20.0], [20.0, 40.0])]  # the 3 seeds; the td3bc run alone has no band
    assert len(lines) == 2 and "mean of 3 seeds" in lines[0] and "TD3" in lines[1]


def test_trajectory_goals_have_their_flights_colour(tmp_path, monkeypatch):
    from mpl_toolkits.mplot3d import Axes3D

    d = tmp_path / "run" / "eval" / "reach-desired"
    d.mkdir(parents=True)
    n, T = 6, 50
    rng = np.random.default_rng(0)
    goals = np.zeros((n, 15))
    goals[:, :3] = rng.uniform(-2, 2, (n, 3))
    pos = np.linspace(0, 1, T)[None, :, None] * goals[:, None, :3]
    np.savez(
        d / "trajectories-step-000000100.npz",
        positions=pos,
        goals=goals,
        start_states=np.zeros((n, 18)),
        steps=np.full(n, T - 1),
        success=np.arange(n) % 2 == 0,
    )
    paths, stars = [], []
    real_plot, real_scatter = Axes3D.plot, Axes3D.scatter

    def plot(self, x, y, z, *a, **kw):
        paths.append((tuple(np.round([x[-1], y[-1], z[-1]], 6)), kw.get("color")))
        return real_plot(self, x, y, z, *a, **kw)

    def scatter(self, x, y, z, *a, **kw):
        if kw.get("marker") == "*":
            stars.append((tuple(np.round(np.ravel([x, y, z]), 6)), kw.get("color")))
        return real_scatter(self, x, y, z, *a, **kw)

    monkeypatch.setattr(Axes3D, "plot", plot)
    monkeypatch.setattr(Axes3D, "scatter", scatter)
    plots.plot_trajectories(tmp_path / "run", "reach-desired", tmp_path / "t.png")
    assert len(paths) == len(stars) == n
    by_end = dict(paths)
    for where, colour in stars:  # each flight ends on its goal here: the star sits where its path ends
        assert by_end[where] == colour
    assert len({c for _, c in stars[:3]}) == 3  # flights of one panel differ
