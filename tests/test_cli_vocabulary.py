"""One CLI vocabulary: every command's parser takes the common flags
where they mean something (--out, --quiet, --threads, --seed, --device), the 0.x
spellings are unknown arguments, help texts show choices, and
``train --config`` round-trips a run's run.toml. Parse level only: nothing trains."""

from __future__ import annotations

import argparse
import dataclasses
import subprocess
import sys

import pytest

from aerohrl.cli_common import COMMON, run_name

# every command (as a parser factory and the argv prefix that selects it) and the common
# flags it takes; a flag missing here is one that means nothing for the command (README
# "Command-line conventions")


def _train():
    from aerohrl.algorithms.cli import parser

    return parser(), []


def _datagen(*sub):
    def make():
        from aerohrl.datagen.cli import parser

        return parser(), list(sub)

    return make


def _eval(sub=None):
    def make():
        from aerohrl.eval import cli

        p = {None: cli._eval_parser, "table": cli._table_parser, "plot": cli._plot_parser, "oracle": cli._oracle_parser}[sub]()
        return p, []

    return make


def _runs():
    from aerohrl.runs import parser

    return parser(), ["show", "runs/r"]


def _ipp(*sub):
    def make():
        from aerohrl.ipp.cli import _parser

        return _parser(), list(sub)

    return make


def _sweep():
    from aerohrl.sweep import parser

    return parser(), []


# name -> (factory, the arguments a parse needs besides the common flags, the common flags taken)
COMMANDS = {
    "train": (_train, [], {"out", "quiet", "threads", "seed", "device"}),
    "datagen build": (_datagen("build"), [], {"out", "quiet", "threads", "seed"}),
    "datagen export": (_datagen("export", "ds", "--format", "ogbench"), [], {"out"}),
    "datagen export-mcap": (_datagen("export-mcap", "ds", "--episode", "0"), [], {"out"}),
    "datagen plot": (_datagen("plot", "ds"), [], {"out"}),
    "aerohrl eval": (_eval(), ["--task", "ood", "--run", "r"], {"out", "quiet", "threads", "seed", "device"}),
    "aerohrl eval table": (_eval("table"), ["r"], {"out"}),
    "aerohrl eval plot": (_eval("plot"), [], {"out"}),
    "aerohrl eval oracle": (_eval("oracle"), ["--run", "r"], {"out", "quiet", "threads", "seed"}),
    "aerohrl runs show": (_runs, [], {"out"}),
    "aerohrl ipp train": (_ipp("train"), [], {"out", "quiet", "threads", "seed"}),
    "aerohrl ipp bench": (_ipp("bench"), [], {"out", "quiet", "threads", "seed"}),
    "aerohrl ipp show": (_ipp("show"), [], {"out", "seed"}),
    "aerohrl ipp curve": (_ipp("curve", "r"), [], {"out"}),
    "aerohrl ipp lattice build": (_ipp("lattice", "build"), [], {"out"}),
    "aerohrl sweep": (_sweep, [], {"out", "device"}),
}
VALUES = {
    "out": ["--out", "x/y"],
    "quiet": ["--quiet"],
    "threads": ["--threads", "3"],
    "seed": ["--seed", "5"],
    "device": ["--device", "cpu"],
}
EXPECTED = {"out": "x/y", "quiet": True, "threads": 3, "seed": 5, "device": "cpu"}


@pytest.mark.parametrize("name", list(COMMANDS))
def test_every_command_takes_the_common_flags(name):
    factory, extra, common = COMMANDS[name]
    p, prefix = factory()
    argv = prefix + extra + [x for k in sorted(common) for x in VALUES[k]]
    a = p.parse_args(argv)
    for k in common:
        got = getattr(a, k)
        assert (str(got) if k == "out" else got) == EXPECTED[k], (name, k, got)
    assert set(common) <= set(COMMON)


@pytest.mark.parametrize("name", [n for n, (_, _, c) in COMMANDS.items() if "out" in c])
def test_o_is_the_short_form_of_out(name):
    factory, extra, _ = COMMANDS[name]
    p, prefix = factory()
    assert str(p.parse_args(prefix + extra + ["-o", "z"]).out) == "z"


OLD_SPELLINGS = [  # (command, a 0.x spelling with its value): gone, each an unknown argument now
    ("train", ["--no-progress"]),
    ("aerohrl eval", ["--no-progress"]),
    ("aerohrl eval oracle", ["--no-progress"]),
    ("aerohrl eval table", ["--output", "t"]),
    ("aerohrl eval plot", ["--output", "f.png"]),
    ("datagen plot", ["--output", "f.png"]),
    ("datagen export-mcap", ["--output", "e.mcap"]),
    ("datagen export", ["--output", "d.npz"]),
    ("aerohrl runs show", ["--output", "c.png"]),
    ("aerohrl ipp bench", ["--out-dir", "b"]),
    ("aerohrl ipp bench", ["--no-progress"]),
    ("aerohrl ipp train", ["--no-progress"]),
    ("aerohrl ipp train", ["--run-dir", "runs/r"]),
    ("aerohrl ipp lattice build", ["--output", "l.npz"]),
    ("aerohrl ipp show", ["--output", "s.png"]),
    ("aerohrl ipp curve", ["--output", "c.png"]),
]


@pytest.mark.parametrize("name,old", OLD_SPELLINGS, ids=[f"{n} {o[0]}" for n, o in OLD_SPELLINGS])
def test_old_spellings_are_unknown_arguments(name, old, capsys):
    factory, extra, common = COMMANDS[name]
    p, prefix = factory()
    required = ["--out", "x"] if "out" in common else []
    from aerohrl.errors import UserError

    try:  # argparse's one-line usage error, or a UserError that the command prints as one line (ipp)
        p.parse_args(prefix + extra + required + old)
    except SystemExit as e:
        assert e.code == 2
        err = capsys.readouterr().err.strip().splitlines()
    except UserError as e:
        err = [str(e)]
    else:
        raise AssertionError(f"{name} accepted {old[0]}")
    assert len(err) == 1 and "unrecognized arguments: " + old[0] in err[0], err


def test_a_required_out_is_required(capsys):
    from aerohrl.datagen.cli import parser

    with pytest.raises(SystemExit) as e:
        parser().parse_args(["plot", "ds"])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "required: -o/--out" in err[0]
    assert str(parser().parse_args(["plot", "ds", "--out", "p.png"]).out) == "p.png"


# ----------------------------------------------------------------------------- help texts


def test_choices_are_shown_and_checked(capsys):
    from aerohrl.algorithms.cli import parser

    text = parser().format_help()
    for choice in (
        "{gcsl,td3bc,td3awbc,cql,gciql,crl,qrl,hiql}",
        "{constant,cosine}",
        "{auto,none,bf16}",
        "{expert,executed}",
        "{cpu,fast,thesis}",
    ):
        assert choice in text, choice
    with pytest.raises(SystemExit):
        parser().parse_args(["--algo", "sac"])
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "invalid choice: 'sac'" in err[0]


def test_train_help_shows_units_cpu_defaults_and_per_algorithm_values():
    from aerohrl.algorithms.cli import parser

    text = " ".join(parser().format_help().split())
    assert "cap on the relabelling offset (0: to the episode's end) (steps) [cpu: 0]" in text
    assert "[cpu: 0.05; gcsl: 0.01]" in text  # relabel_prob: the cpu preset's [algo.gcsl] table
    assert "--alpha N TD3-BC alpha" in text and "{constant,linear}" in text and "{std,none}" in text


def test_every_train_setting_declares_its_meaning():
    """Every setting (sections included) is declared with param(default, "meaning", ...)."""
    from aerohrl import config as K
    from aerohrl.algorithms import config as C

    missing = [f.name for _, f, _ in K.leaves(C.TrainConfig) if not f.metadata.get("help")]
    assert not missing, missing


def test_every_flag_has_help():
    """Every option of every command says what it is."""
    undocumented = []
    for name, (factory, _, _) in COMMANDS.items():
        p, prefix = factory()
        for sub in prefix:  # the subcommand's own parser
            sp = next((a for a in p._actions if isinstance(a, argparse._SubParsersAction)), None)
            if sp is None or sub not in sp.choices:
                break
            p = sp.choices[sub]
        undocumented += [
            f"{name} {a.option_strings[-1]}" for a in p._actions if a.option_strings and a.help is None and a.dest != "help"
        ]
    assert not undocumented, undocumented


def test_help_constants_match_their_sources():
    """The constants that keep `aerohrl ipp --help` free of scipy and torch, and the
    datagen vehicle choices, equal the values they stand for."""
    from aerohrl.datagen.cli import SPEC_CHOICES
    from aerohrl.ipp import baselines, bench, cli, env, train
    from aerohrl.sim.params import PRESETS as VEHICLES

    assert cli.PLANNERS == baselines.PLANNERS and cli.TEACHERS == baselines.TEACHERS
    assert cli.TEST_SEED == bench.TEST_SEED and cli.BUDGETS == env.BUDGETS and cli.SEMANTIC_BUDGET == env.SEMANTIC_BUDGET
    ec = env.EnvConfig()
    assert cli.ENV_DEFAULTS == {"map_size": ec.map_size, "budget": ec.budget, "start": ec.start}
    assert tuple(train.PRESETS) == train.preset_names()  # ipp train's flags come from TrainConfig itself
    assert set(SPEC_CHOICES["vehicle"]) == set(VEHICLES)


def test_eval_family_choices_match_the_families():
    from aerohrl.eval import cli
    from aerohrl.eval.families import FAMILIES

    p = cli._eval_parser()
    fam = next(a for a in p._actions if a.dest == "family")
    assert tuple(fam.choices) == tuple(FAMILIES)


@pytest.mark.parametrize("argv", [["train"], ["aerohrl", "ipp", "train"], ["aerohrl", "eval"], ["datagen", "build"]])
def test_help_imports_no_torch(argv):
    """--help loads neither torch nor lerobot (lazy imports: the help is fast)."""
    entry = {"train": "aerohrl.algorithms.cli", "datagen": "aerohrl.datagen.cli", "aerohrl": "aerohrl.cli"}[argv[0]]
    code = (
        f"import sys\nfrom {entry} import main\ntry:\n    main({argv[1:] + ['--help']!r})\nexcept SystemExit:\n    pass\n"
        "heavy = sorted(m for m in ('torch', 'lerobot', 'scipy.ndimage', 'torchrl') if m in sys.modules)\n"
        "print('HEAVY', heavy)"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip().splitlines()[-1] == "HEAVY []", r.stdout[-300:]


# ----------------------------------------------------------------------------- run names


def test_runs_are_named_one_way(monkeypatch):
    import re

    from aerohrl.algorithms import config as C
    from aerohrl.algorithms.run import new_run_dir

    shape = r"-s(\d+)-\d{8}-\d{6}-[0-9a-f]{6}$"
    assert re.fullmatch(r"gcsl-cpu" + shape, new_run_dir(C.make_config("cpu", seed=4), "runs").name)
    assert re.fullmatch(r"ipp-cpu-nornn" + shape, run_name("ipp", "cpu", "nornn", seed=7))
    assert re.fullmatch(r"ipp-cpu" + shape, run_name("ipp", "cpu", None, seed=7))


# ----------------------------------------------------------------------------- train --config


def _cfg(argv):
    from aerohrl.algorithms.cli import config_from_args, parser

    return config_from_args(parser().parse_args(argv))


def test_config_round_trip(tmp_path):
    """save -> load -> the same config; flags override the file's values."""
    from aerohrl.algorithms import config as C

    cfg = C.make_config(
        "thesis",
        algo="td3bc",
        dataset="/data/ds",
        seed=3,
        hidden=(64, 32),
        critic_hidden=(),
        amp="bf16",
        lr_actor=2.5e-4,
        mc_lower_bound=True,
    )
    f = tmp_path / C.TOML_NAME
    f.write_text(C.to_toml(cfg))
    assert _cfg(["--config", str(f)]) == cfg
    over = _cfg(["--config", str(f), "--seed", "9", "--steps", "77", "--hidden", "8", "8", "--no-mc-lower-bound"])
    assert over == dataclasses.replace(cfg, seed=9, steps=77, hidden=(8, 8), mc_lower_bound=False)
    assert _cfg(["--config", str(f), "--preset", "cpu"]).preset == "cpu"  # --preset wins over the file's


def test_config_file_may_be_partial(tmp_path):
    from aerohrl.algorithms import config as C

    f = tmp_path / "c.toml"
    f.write_text('algo = "cql"\ndataset = "d"\nsteps = 100\nrelabel_mean_offset = 12\n')
    cfg = _cfg(["--config", str(f)])
    assert cfg == C.make_config("cpu", algo="cql", dataset="d", steps=100, relabel_mean_offset=12.0)
    assert isinstance(cfg.relabel_mean_offset, float)


@pytest.mark.parametrize(
    "text,match",
    [
        ('algo = "gcsl"\nlearning_rate = 1e-3\n', "unknown key(s) learning_rate"),
        ('steps = "many"\n', "steps must be an integer"),
        ('hidden = [64, "x"]\n', "hidden must be a list of integers"),
        ('algo = "gcsl"\nsteps = \n', "is not valid TOML"),
        ('algo = "sac"\ndataset = "d"\n', "algo must be one of gcsl, td3bc, td3awbc, cql, gciql, crl, qrl, hiql, got 'sac'"),
    ],
)
def test_bad_config_file_is_one_line(tmp_path, capsys, text, match):
    from aerohrl.algorithms.cli import main

    f = tmp_path / "bad.toml"
    f.write_text(text)
    assert main(["--config", str(f), "--out", str(tmp_path / "runs")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("train: error: ") and match in err[0], err
    assert not (tmp_path / "runs").exists()  # refused before anything is created


def test_missing_config_file_is_one_line(tmp_path, capsys):
    from aerohrl.algorithms.cli import main

    assert main(["--config", str(tmp_path / "nope.toml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"train: error: no config file at {tmp_path / 'nope.toml'}"]


def test_config_and_resume_do_not_mix(tmp_path, capsys):
    from aerohrl.algorithms.cli import main

    f = tmp_path / "c.toml"
    f.write_text('algo = "gcsl"\n')
    assert main(["--config", str(f), "--resume", str(tmp_path)]) == 2
    assert "--config starts a new run" in capsys.readouterr().err


@pytest.mark.parametrize("argv", [["--threads", "0"], ["--seed", "-1"], ["--threads", "x"]])
def test_bad_common_values_are_one_line(argv, capsys):
    from aerohrl.algorithms.cli import main

    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("train: error: argument --")


def test_run_toml_is_written_beside_config_json(data, tmp_path):
    """Every run saves run.toml with config.json (and again on --resume, with what changed);
    `train --config RUN/run.toml` gives that config back."""
    from aerohrl.algorithms import config as C
    from aerohrl.algorithms.trainer import resume_run, start_run

    tiny = dict(hidden=(16, 16), critic_hidden=(16, 16), batch_size=32, steps=4, log_every=2, checkpoint_every=2, eval_every=0)
    cfg = C.make_config("cpu", algo="gcsl", dataset=str(data.info["path"]), **tiny)
    start_run(cfg, tmp_path / "r", data=data, progress=False, logger="none").train()
    run_toml = tmp_path / "r" / C.TOML_NAME
    saved = C.from_dict(__import__("json").loads((tmp_path / "r" / "config.json").read_text())["config"])
    assert _cfg(["--config", str(run_toml)]) == saved
    resume_run(tmp_path / "r", data=data, progress=False, overrides={"steps": 6}).train()
    assert _cfg(["--config", str(run_toml)]) == dataclasses.replace(saved, steps=6)


def test_threads_sets_torch_and_openmp(monkeypatch):
    import os

    import torch

    from aerohrl.cli_common import set_threads

    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        monkeypatch.delenv(var, raising=False)
    old = torch.get_num_threads()
    try:
        set_threads(None)
        assert "OMP_NUM_THREADS" not in os.environ and torch.get_num_threads() == old  # not given: defaults stay
        set_threads(2, torch=False)
        assert os.environ["OMP_NUM_THREADS"] == "2" and torch.get_num_threads() == old
        set_threads(1)
        assert os.environ["OPENBLAS_NUM_THREADS"] == "1" and torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(old)


@pytest.mark.parametrize("name", ["aerohrl runs show", "aerohrl ipp curve"])
def test_a_run_is_positional_or_a_flag(name, capsys):
    from aerohrl.errors import UserError

    factory, _, _ = COMMANDS[name]
    p, prefix = factory()
    prefix = prefix[:1]  # the subcommand without its run
    assert str(p.parse_args(prefix + ["runs/a"]).run) == "runs/a"
    assert str(p.parse_args(prefix + ["--run", "runs/a"]).run) == "runs/a"  # aerohrl eval's spelling
    assert not hasattr(p.parse_args(prefix + ["runs/a"]), "run_flag")
    for argv in (prefix, prefix + ["runs/a", "--run", "runs/b"]):
        with pytest.raises((SystemExit, UserError)):
            p.parse_args(argv)


def test_library_value_errors_are_one_line(capsys, monkeypatch):
    """A library's ValueError or TypeError reaches the user as one line and exit 2 (a
    UserError is a ValueError); AEROHRL_TRACEBACK=1 shows the traceback instead."""
    from aerohrl.errors import UserError, run_cli

    assert issubclass(UserError, ValueError)

    def bad():
        raise ValueError("waypoint count must be >= 1, got 0\nsecond line")

    monkeypatch.delenv("AEROHRL_TRACEBACK", raising=False)
    assert run_cli("demo", bad) == 2
    assert capsys.readouterr().err == "demo: error: waypoint count must be >= 1, got 0\n"
    monkeypatch.setenv("AEROHRL_TRACEBACK", "1")
    with pytest.raises(ValueError, match="waypoint count"):
        run_cli("demo", bad)
    with pytest.raises(ZeroDivisionError):  # a bug is not a refusal: its traceback stays
        run_cli("demo", lambda: 1 / 0)
