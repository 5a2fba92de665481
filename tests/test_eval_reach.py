"""OOD goal families (eval/families.py) and the reach study (eval/rings.py, experiments/reach_study.py): rings and their
one-line errors, the thesis's OOD set as ring 1, batched rings equal to one evaluation each,
the decline margin chosen on held-out goals and applied exactly."""

import csv
import json
import math
import warnings

import numpy as np
import pytest
import torch

from aerohrl.algorithms.config import make_config
from aerohrl.algorithms.synthetic import write_synthetic_dataset
from aerohrl.algorithms.trainer import start_run
from aerohrl.cli import main
from aerohrl.datagen.goals import goal_vectors
from aerohrl.errors import UserError
from aerohrl.eval import families as F
from aerohrl.eval import rings as reach
from aerohrl.eval.tasks import ood_goals
from conftest import load_experiment

warnings.filterwarnings("ignore", category=UserWarning)
TINY = dict(
    hidden=(16, 16),
    critic_hidden=(16, 16),
    batch_size=32,
    steps=40,
    log_every=10,
    checkpoint_every=20,
    eval_every=0,
    eval_episodes=2,
    eval_horizon=20,
)


def test_position_ring_1_is_the_thesis_ood_set():
    ring = F.parse_ring("position", "1")
    for seed in (0, 3):
        assert np.array_equal(goal_vectors(F.sample_ring(ring, 40, seed)), ood_goals(40, seed))
    assert ring.horizon() == 1000  # two legs of 500, as the thesis flies it


@pytest.mark.parametrize("family", list(F.FAMILIES))
def test_rings_leave_rho_d_along_their_dimension_only(family):
    for ring in F.rings(family):
        g = F.sample_ring(ring, 300, 0)
        for dim, key in (("pos", "pos"), ("vel", "vel"), ("acc", "acc")):
            x = np.abs(g[key])
            if dim in ring.ranges:
                lo, hi = ring.ranges[dim]
                if dim == "acc":  # z may be flipped up (thrust rule) but keeps its magnitude
                    assert (x >= lo - 1e-12).all() and (x <= hi + 1e-12).all()
                    assert (9.81 + g["acc"][:, 2] >= F.MIN_THRUST_Z).all()
                else:
                    assert (x >= lo).all() and (x <= hi).all()
                assert (np.sign(g[key]) < 0).any() and (np.sign(g[key]) > 0).any()
            else:  # drawn from rho_D (SPEC ranges)
                bound = {"pos": 2.0, "vel": 2.5, "acc": 5.0}[dim]
                assert (x <= bound + 1e-12).all()
        # attitude from the acceleration by flatness: body z along a + g e3
        f = g["acc"] + np.array([0, 0, 9.81])
        z = g["R"][:, :, 2]
        assert np.allclose(z, f / np.linalg.norm(f, axis=1, keepdims=True), atol=1e-9)


def test_horizons_scale_with_distance_and_streams_differ():
    hs = [r.horizon() for r in F.rings("position")]
    assert hs == sorted(hs) and hs[0] == 1000 and hs[-1] == 6000
    assert F.parse_ring("velocity", "2").horizon() == 1000 and F.rings("combined")[0].horizon() == 1500
    a = F.sample_ring(F.parse_ring("velocity", "1"), 10, 0)["pos"]
    b = F.sample_ring(F.parse_ring("velocity", "2"), 10, 0)["pos"]
    c = F.sample_ring(F.parse_ring("velocity", "1"), 10, 1)["pos"]
    assert not np.allclose(a, b) and not np.allclose(a, c)


@pytest.mark.parametrize(
    "family, ring, msg",
    [
        ("speed", "1", "unknown goal family"),
        ("velocity", "4", "rings 1..3"),
        ("velocity", "0", "rings 1..3"),
        ("velocity", "x", "step 1..3 or a range"),
        ("velocity", "5:3", "LO < HI"),
        ("velocity", "1:99", "beyond what"),
        ("combined", "1:2", "fixed rings only"),
    ],
)
def test_bad_rings_are_one_line_errors(family, ring, msg):
    with pytest.raises(UserError, match=msg):
        F.parse_ring(family, ring)


def test_custom_ring():
    r = F.parse_ring("velocity", "4:6")
    v = np.abs(F.sample_ring(r, 100, 0)["vel"])
    assert r.index == 0 and (v >= 4).all() and (v <= 6).all() and r.slug == "velocity-4-6"


def test_decline_and_margin_choice():
    s = np.array([1, 0, 1, 0], bool)
    p = np.array([0, 1, 1, 0], bool)
    d = np.array([0.5, 0.2, -0.1, 0.05])
    assert reach.decline_success(s, p, d, 0.1).tolist() == [False, True, True, False]
    assert reach.decline_success(s, p, d, math.inf).tolist() == s.tolist()
    # ring A: the planner helps where its margin is large; ring B: it hurts where it is small
    pairs = {
        "A": [(np.array([0, 0], bool), np.array([1, 1], bool), np.array([0.4, 0.3]))],
        "B": [(np.array([1, 1], bool), np.array([0, 0], bool), np.array([0.01, 0.02]))],
    }
    m, table = reach.choose_margin(pairs)
    assert 0.02 <= m < 0.3 and table[m]["worst"] == 0.0 and table[m]["mean"] == 0.5
    # a margin that loses under a point on one ring but gains a lot on another is taken
    pairs_c = {
        "A": [(np.zeros(2, bool), np.ones(2, bool), np.array([0.004, 0.004]))],
        "C": [(np.ones(200, bool), np.r_[np.zeros(1, bool), np.ones(199, bool)], np.full(200, 0.002))],
    }
    m, table = reach.choose_margin(pairs_c)
    assert m == 0.0 and table[m]["worst"] == pytest.approx(-0.005) and table[m]["mean"] == pytest.approx(0.4975)
    m, _ = reach.choose_margin(pairs_c, max_loss=0.0)  # no loss allowed: decline where it would cost
    assert m >= 0.005 and math.isinf(m)
    # nothing ever helps: decline always
    m, _ = reach.choose_margin({"B": pairs["B"]})
    assert m == max(reach.MARGIN_GRID)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    torch.set_num_threads(1)
    root = tmp_path_factory.mktemp("reach")
    ds = write_synthetic_dataset(root / "ds")
    cfg = make_config("cpu", algo="gcsl", dataset=str(ds), **TINY)
    start_run(cfg, root / "runs" / "gcsl", progress=False).train()
    return root / "runs" / "gcsl"


def _success(d):
    f = sorted(d.glob("episodes-step-*.csv"))[-1]
    return [r["success"] for r in csv.DictReader(open(f))], [r["goal_px"] for r in csv.DictReader(open(f))]


def test_reach_study_end_to_end(run, tmp_path, capsys):
    study = load_experiment("reach_study")
    pages = tmp_path / "pages"
    argv = [
        "--runs",
        str(run),
        "--families",
        "velocity",
        "--episodes",
        "5",
        "--heldout",
        "4",
        "--variants",
        "straight",
        "single",
        "single-decline",
        "chain",
        "--candidates",
        "64",
        "--out",
        str(tmp_path / "out"),
        "--results-dir",
        str(pages),
        "--fly-declines",
    ]
    assert study.main(argv) == 0
    (page,) = pages.glob("*-reach-families.md")
    text = page.read_text()
    assert text.index("```\npython experiments/reach_study.py --runs") < text.index("Written by")  # the command first
    assert "\\|v_i\\| in [3.5, 5] m/s" in text and "reach_curves.png)" in text
    assert (pages / "figures" / page.name.replace(".md", "-reach_curves.png")).stat().st_size > 0
    margins = json.loads((tmp_path / "out" / "reach-margins.json").read_text())["margins"]
    assert "single" in margins and "chain" in margins
    chain = json.loads((reach.eval_root(run, 5) / "ood-velocity-3.5-5-multi2-synth" / "summary.json").read_text())
    assert chain["options"]["candidate_source"] == "synthetic" and chain["options"]["candidates"] == reach.CHAIN_CANDIDATES
    # the batched rings equal one `aerohrl eval` per ring
    ring_dir = reach.eval_root(run, 5) / "ood-velocity-3.5-5-none"
    assert json.loads((ring_dir / "summary.json").read_text())["episodes"] == 5
    solo = tmp_path / "solo"
    assert (
        main(
            [
                "eval",
                "--task",
                "ood",
                "--family",
                "velocity",
                "--ring",
                "2",
                "--run",
                str(run),
                "--episodes",
                "5",
                "--checkpoints",
                "1",
                "--out",
                str(solo),
                "--quiet",
            ]
        )
        == 0
    )
    assert _success(solo) == _success(ring_dir)
    # held-out goals are other goals
    held = reach.eval_root(run, 5) / "heldout" / "ood-velocity-3.5-5-none"
    assert _success(held)[1][:4] != _success(ring_dir)[1][:4]
    # the declining planner flies exactly the composition of its two flights
    m = margins["single"]
    if not math.isinf(m):
        single = reach.eval_root(run, 5) / "ood-velocity-3.5-5-single"
        dec = reach.eval_root(run, 5) / f"ood-velocity-3.5-5-single-decline{m:g}"
        e_s, e_p, e_d = (reach.episode_outcomes(x) for x in (ring_dir, single, dec))
        for k in e_d:
            assert np.array_equal(
                e_d[k]["success"], reach.decline_success(e_s[k]["success"], e_p[k]["success"], e_p[k]["diff"], m)
            )
    assert (tmp_path / "out" / "reach_curves.png").stat().st_size > 0
    # resumable: a second pass flies nothing new and writes the same table
    mtime = ring_dir.joinpath("summary.json").stat().st_mtime
    assert study.main(argv) == 0 and ring_dir.joinpath("summary.json").stat().st_mtime == mtime


@pytest.mark.parametrize(
    "args, msg",
    [
        (["--family", "speed"], "invalid choice: 'speed'"),
        (["--family", "velocity", "--ring", "9"], "rings 1..3"),
        (["--ring", "2"], "--ring needs --family"),
    ],
)
def test_eval_cli_family_errors(run, capsys, args, msg):
    try:
        code = main(["eval", "--task", "ood", "--run", str(run), "--quiet", *args])
    except SystemExit as e:  # a usage error found while parsing (a choice): one line, exit 2
        code = e.code
    err = capsys.readouterr().err.strip()
    assert code == 2 and msg in err and len(err.splitlines()) == 1
    code = main(["eval", "--task", "reach-novel", "--family", "velocity", "--run", str(run), "--quiet"])
    assert code == 2 and "apply to --task ood only" in capsys.readouterr().err


def test_oracle_on_a_family_ring_with_synthetic_candidates(run, tmp_path, capsys):
    out = tmp_path / "oracle"
    assert (
        main(
            [
                "eval",
                "oracle",
                "--run",
                str(run),
                "--family",
                "velocity",
                "--ring",
                "2",
                "--candidate-source",
                "synthetic",
                "--goals",
                "3",
                "--candidates",
                "4",
                "--leg-horizon",
                "20",
                "--out",
                str(out),
                "--quiet",
            ]
        )
        == 0
    )
    r = json.loads((out / "oracle.json").read_text())
    assert r["task"] == "ood-velocity-3.5-5-synth" and r["candidates"] == 4 and r["goals"] == 3
    assert 0.0 <= r["oracle"] <= 1.0 and r["planner"] <= r["oracle"]
    code = main(["eval", "oracle", "--run", str(run), "--ring", "2", "--quiet"])
    assert code == 2 and "--ring needs --family" in capsys.readouterr().err


def test_synthetic_candidates_lie_in_rho_d():
    from aerohrl.planning.oracle import synthetic_candidates

    c = synthetic_candidates({"pos_range": [1, 2], "vel_range": [-2.5, 2.5], "acc_range": [-5, 5]}, 50, 0)
    assert len(c) == 50 and c.states.shape == (50, 18) and (c.goals[:, :3].abs() <= 2).all()
    assert (c.goals[:, 3:6].abs() <= 2.5).all() and torch.equal(c.states[:, :15], c.goals)
