"""The config layer (aerohrl.config): one declaration per setting gives validation, the
unknown-key check, TOML and flags."""

from __future__ import annotations

import math
from dataclasses import dataclass

import pytest

from aerohrl import config as K
from aerohrl.errors import ArgumentParser


@dataclass
class Actor:
    alpha: float = K.param(0.5, "weight of the Q-term", ge=0)
    schedule: str = K.param("linear", "alpha over the run", choices=("constant", "linear"))


@dataclass
class Cfg:
    steps: int = K.param(100, "gradient steps", ge=1)
    lr: float = K.param(1e-3, "learning rate", unit="1/step", gt=0)
    hidden: tuple[int, ...] = K.param((8, 8), "hidden sizes", unit="units", ge=1)
    expectile: float = K.param(0.7, "expectile", gt=0, lt=1)
    ema: bool = K.param(True, "average the weights")
    name: str = K.param("", "the run's name", flag=False)
    actor: Actor = K.section(Actor, "the actor")


def test_defaults_validate_and_each_bound_is_one_line():
    K.validate(Cfg())
    for values, match in (
        ({"steps": 0}, "steps must be >= 1, got 0"),
        ({"lr": 0.0}, "lr must be > 0"),
        ({"expectile": 1.0}, "expectile must be < 1"),
        ({"hidden": [8, 0]}, "hidden must be >= 1"),
        ({"alpha": -1.0}, "alpha must be >= 0"),
        ({"schedule": "cosine"}, "schedule must be one of constant, linear"),
        ({"lr": math.nan}, "lr must be a finite number"),
    ):
        with pytest.raises(K.ConfigError, match=match) as e:
            K.from_mapping(Cfg, values, where="f.toml")
        assert "\n" not in str(e.value) and isinstance(e.value, ValueError)


def test_mappings_coerce_nest_and_refuse_unknown_keys():
    c = K.from_mapping(Cfg, {"steps": 5, "lr": 1, "hidden": [4], "alpha": 2})
    assert (c.steps, c.lr, c.hidden, c.actor.alpha) == (5, 1.0, (4,), 2.0) and isinstance(c.lr, float)
    assert K.from_mapping(Cfg, {"actor": {"schedule": "constant"}}).actor.schedule == "constant"  # a section as a sub-table
    with pytest.raises(K.ConfigError, match=r"f.toml: unknown key\(s\) stesp \(did you mean steps\?\)"):
        K.from_mapping(Cfg, {"stesp": 5}, where="f.toml")
    for bad, what in (
        ({"steps": 1.5}, "an integer"),
        ({"ema": 1}, "true or false"),
        ({"hidden": [1.5]}, "a list of integers"),
        ({"schedule": 3}, "a string"),
    ):
        with pytest.raises(K.ConfigError, match=what):
            K.from_mapping(Cfg, bad)


def test_toml_round_trip_and_presets(tmp_path):
    c = K.from_mapping(Cfg, {"steps": 7, "hidden": [3, 2], "schedule": "constant", "name": "r"})
    (tmp_path / "run.toml").write_text(K.to_toml(c, header="a run"))
    assert K.from_mapping(Cfg, K.load_toml(tmp_path / "run.toml")) == c
    (tmp_path / "fast.toml").write_text("steps = 3\n")
    assert K.preset_names(tmp_path) == ("fast", "run")
    assert K.from_mapping(Cfg, K.load_preset(tmp_path, "fast")).steps == 3
    with pytest.raises(K.ConfigError, match="unknown preset 'slow' \\(choose from fast, run\\)"):
        K.load_preset(tmp_path, "slow")
    (tmp_path / "bad.toml").write_text("steps = = 3\n")
    with pytest.raises(K.ConfigError, match="is not valid TOML"):
        K.load_toml(tmp_path / "bad.toml")


def test_flags_come_from_the_fields(capsys):
    p = ArgumentParser(prog="demo")
    K.add_flags(p, Cfg, default_label="cpu")
    text = p.format_help()
    assert "--steps" in text and "--hidden" in text and "--alpha" in text and "--no-ema" in text and "--name" not in text
    assert "learning rate (1/step) [cpu: 0.001]" in " ".join(text.split())
    a = p.parse_args(["--steps", "3", "--hidden", "4", "4", "--schedule", "constant", "--no-ema"])
    assert K.given_flags(a, Cfg) == {"steps": 3, "hidden": (4, 4), "ema": False, "schedule": "constant"}
    for argv, match in (
        (["--steps", "0"], "must be >= 1, got 0"),
        (["--expectile", "1"], "must be < 1"),
        (["--lr", "nan"], "finite"),
        (["--schedule", "x"], "invalid choice"),
    ):
        with pytest.raises(SystemExit) as e:
            p.parse_args(argv)
        err = capsys.readouterr().err.strip().splitlines()
        assert e.value.code == 2 and len(err) == 1 and match in err[0], err


def test_a_setting_declared_twice_is_refused():
    @dataclass
    class Twice:
        alpha: float = K.param(1.0, "clash")
        actor: Actor = K.section(Actor)

    with pytest.raises(TypeError, match="declared twice"):
        K.from_mapping(Twice, {})
    with pytest.raises(TypeError, match="mutable default"):
        K.param([1], "a list")


@dataclass
class Grid:
    algos: tuple[str, ...] = K.param((), "algorithms", choices=("a", "b"))
    seeds: tuple[int, ...] = K.param((0,), "seeds", ge=0)
    path: str = K.param("", "a path")
    set: dict = K.param({}, "overrides of every run")


def test_tuple_choices_hold_for_each_element_and_tables_are_dicts():
    g = K.from_mapping(Grid, {"algos": ["a", "b"], "set": {"steps": 3}})
    assert g.algos == ("a", "b") and g.set == {"steps": 3}
    assert Grid().set == {} and Grid().set is not Grid().set  # a table is copied for each instance
    with pytest.raises(K.ConfigError, match="algos must be one of a, b, got 'c'"):
        K.from_mapping(Grid, {"algos": ["a", "c"]})
    with pytest.raises(K.ConfigError, match="set must be a table"):
        K.from_mapping(Grid, {"set": 3})
    with pytest.raises(K.ConfigError, match=r"unknown key\(s\) eval"):  # only a section may be a sub-table
        K.from_mapping(Grid, {"eval": {"seeds": [1]}})


def test_flag_help_notes_and_no_empty_default():
    p = ArgumentParser(prog="demo")
    K.add_flags(p, Grid, notes={"seeds": "b: 1 2"}, default_label="cpu")
    text = " ".join(p.format_help().split())
    assert "seeds [cpu: 0; b: 1 2]" in text and "a path" in text and "a path [" not in text and "--set" not in text


@dataclass
class Sensor:
    size: int = K.param(3, "footprint", unit="cells", ge=1)
    depth: int | None = K.param(None, "search depth (none: the planner's own)", ge=1)


@dataclass
class World:
    size: int = K.param(30, "cells per side", unit="cells", ge=1)  # the same name as Sensor's: nested only
    sensor: Sensor = K.section(Sensor)


def test_nested_mappings_keep_sections_apart_and_take_none():
    w = K.from_nested(World, {"size": 20, "sensor": {"size": 5, "depth": 2}})
    assert (w.size, w.sensor.size, w.sensor.depth) == (20, 5, 2)
    assert K.from_nested(World, {"sensor": {"depth": None}}).sensor.depth is None
    assert K.from_nested(World, {"size": 12.0}).size == 12  # JSON may write an integer as 12.0
    with pytest.raises(K.ConfigError, match=r"run.json: sensor: unknown key\(s\) sise \(did you mean size\?\)"):
        K.from_nested(World, {"sensor": {"sise": 5}}, where="run.json")
    with pytest.raises(K.ConfigError, match="sensor.depth must be an integer"):
        K.from_nested(World, {"sensor": {"depth": "deep"}})
    with pytest.raises(K.ConfigError, match="depth must be >= 1, got 0"):
        K.from_nested(World, {"sensor": {"depth": 0}})
