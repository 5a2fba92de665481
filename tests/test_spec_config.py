"""DatasetSpec through the config layer: spec files get the one unknown-key and type check,
cross-field rules hold for the whole file (not key by key), and the version names of
existing specs stay what they were."""

from __future__ import annotations

import pytest

from aerohrl.config import ConfigError
from aerohrl.datagen.spec import DatasetSpec, load_spec, version_name


def _spec(tmp_path, text):
    p = tmp_path / "s.toml"
    p.write_text(text)
    return p


def test_spec_files_are_checked_by_the_config_layer(tmp_path):
    with pytest.raises(ConfigError, match=r"s.toml: unknown key\(s\) goal \(did you mean goals\?\)"):
        load_spec(_spec(tmp_path, "goal = 3\n"))
    with pytest.raises(ConfigError, match="goals must be an integer"):
        load_spec(_spec(tmp_path, 'goals = "many"\n'))
    with pytest.raises(ConfigError, match="pos_range must be a list of numbers"):
        load_spec(_spec(tmp_path, 'pos_range = ["a", 2]\n'))
    with pytest.raises(ConfigError, match="is not valid TOML"):
        load_spec(_spec(tmp_path, "goals = = 3\n"))
    with pytest.raises(ConfigError, match=r"spec: unknown key\(s\) colour"):
        load_spec(None, colour="red")
    # degree before solver: each key alone breaks "closed-form is degree 5", the file does not
    spec = load_spec(_spec(tmp_path, 'degree = 7\nsolver = "qp"\nfps = 50\nsubsteps = 10\n'))
    assert (spec.degree, spec.solver, spec.fps * spec.substeps) == (7, "qp", 500)


def test_version_names_are_unchanged(tmp_path):
    # the version names of existing specs; an integer written for a float setting
    # (a_max = 5) hashes as the integer it is
    assert version_name(load_spec(None)) == version_name(DatasetSpec()) == "n250-s0-dbb240c0"
    assert (
        version_name(
            load_spec(
                _spec(tmp_path, "a_max = 5\nt_max = 4\ngoals = 12\npos_range = [1, 2]\naction_noise = [1, 0]\nnoise_tau = 1\n")
            )
        )
        == "n12-s0-409ffd64"
    )
    assert version_name(load_spec(None, a_max=5, t_max=4)) == "n250-s0-ab83c052"
    assert version_name(load_spec(None, goals=25000, action_noise=[1.0, 0.5])) == "n25000-s0-81b96355"
    assert version_name(load_spec(None, expert="replan", replan_every=3)) == "n250-s0-76b2ef0e"
    assert version_name(load_spec(None, start_states="perturbed", start_vel=0.5)) == "n250-s0-ccd1248e"
