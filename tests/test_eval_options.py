"""EvalOptions: declared settings, the cross-field rules, and result-folder names that stay
those of the results already on disk."""

from __future__ import annotations

import pytest

from aerohrl.errors import UserError
from aerohrl.eval.harness import FLOORS, EvalOptions, check_options

# (options, folder name): the names of results already on disk, which must be found again
NAMES = [
    ({}, "reach-desired"),
    ({"task": "reach-novel", "goal_tol": 0.5}, "reach-novel-goaltol0.5"),
    ({"task": "ood"}, "ood-none"),
    ({"task": "ood", "planner": "multi", "waypoints": 4, "candidate_source": "synthetic"}, "ood-multi4-synth"),
    ({"task": "ood", "planner": "single", "decline_margin": 0.05}, "ood-single-decline0.05"),
    ({"task": "ood", "planner": "none", "decline_margin": 0.05}, "ood-none"),
    (
        {
            "task": "ood",
            "waypoints": 4,
            "decline_margin": 0.05,
            "candidate_source": "synthetic",
            "goal_tol": 0.5,
            "family": "position",
            "ring": "2",
        },
        "ood-position-3.5-5-none-goaltol0.5",
    ),
    (
        {
            "task": "ood",
            "planner": "multi",
            "replan_every": 10,
            "waypoint_tol": 2.5,
            "min_leg": 1.5,
            "goal_tol": 0.5,
            "floor": "hover",
            "family": "position",
        },
        "ood-position-2-3.5-multi2-replan10-tol2.5-minleg1.5-goaltol0.5-floor-hover",
    ),
    (
        {
            "task": "ood",
            "planner": "multi",
            "waypoint_tol": 2.5,
            "decline_margin": 0.0,
            "candidate_source": "synthetic",
            "floor": "hover",
        },
        "ood-multi2-tol2.5-decline0-synth-floor-hover",
    ),
    ({"planner": "multi", "waypoints": 4, "replan_every": 10, "min_leg": 1.5}, "reach-desired"),
    (
        {
            "task": "ood",
            "planner": "single",
            "waypoint_tol": 2.5,
            "alpha": 0.5,
            "min_leg": 1.5,
            "goal_tol": 0.5,
            "floor": "hover",
            "family": "position",
        },
        "ood-position-2-3.5-single-tol2.5-a0.5-minleg1.5-goaltol0.5-floor-hover",
    ),
    (
        {
            "task": "ood",
            "planner": "multi",
            "waypoints": 4,
            "alpha": 0.5,
            "decline_margin": 0.0,
            "goal_tol": 0.5,
            "family": "position",
            "ring": "0.5:1",
        },
        "ood-position-0.5-1-multi4-a0.5-decline0-goaltol0.5",
    ),
    (
        {
            "task": "ood",
            "planner": "multi",
            "replan_every": 10,
            "waypoint_tol": 2.5,
            "alpha": 0.5,
            "min_leg": 1.5,
            "decline_margin": 0.05,
            "family": "position",
            "ring": "2",
        },
        "ood-position-3.5-5-multi2-replan10-tol2.5-a0.5-minleg1.5-decline0.05",
    ),
    (
        {"replan_every": 10, "decline_margin": 0.0, "candidate_source": "synthetic", "goal_tol": 0.5, "floor": "hover"},
        "reach-desired-goaltol0.5-floor-hover",
    ),
    (
        {
            "task": "reach-novel",
            "planner": "multi",
            "waypoints": 4,
            "replan_every": 10,
            "alpha": 0.5,
            "min_leg": 1.5,
            "decline_margin": 0.0,
            "floor": "hover",
        },
        "reach-novel-floor-hover",
    ),
    (
        {
            "task": "ood",
            "planner": "single",
            "waypoints": 4,
            "replan_every": 10,
            "floor": "hover",
            "family": "position",
            "ring": "0.5:1",
        },
        "ood-position-0.5-1-single-replan10-floor-hover",
    ),
    (
        {"task": "maze", "planner": "graph", "max_edge": 2.5, "legs": "corridor", "min_leg": 1.0},
        "maze-graph-corridor-edge2.5-minleg1",
    ),
    (
        {"task": "maze", "planner": "graph", "waypoints_from": "data", "candidates": 600, "max_edge": 2.5, "waypoint_tol": 2.5},
        "maze-graph-data600-tol2.5-edge2.5",
    ),
]


@pytest.mark.parametrize("options,name", NAMES)
def test_result_folder_names_are_unchanged(options, name):
    assert EvalOptions(**options).name() == name


def test_declared_checks_and_cross_field_rules():
    from aerohrl.eval.floors import FLOORS as IMPLEMENTED

    assert FLOORS == IMPLEMENTED
    check_options(EvalOptions(task="ood", planner="multi"))
    for options, match in (
        ({"task": "reach-far"}, "task must be one of reach-desired"),
        ({"episodes": 0}, "episodes must be >= 1"),
        ({"goal_tol": 11.0}, "goal_tol must be <= 10"),
        ({"decline_margin": float("inf")}, "decline_margin must be a finite number"),
        ({"min_leg": -1.0}, "min_leg must be >= 0"),
        ({"floor": "ground"}, "floor must be one of none, hover, no-goal"),
        ({"horizon": 0}, "horizon must be >= 1"),
        ({"planner": "single"}, "applies to --task ood only"),
        ({"task": "ood", "planner": "multi", "waypoints": 1}, "needs --waypoints >= 2"),
        ({"task": "ood", "planner": "single", "floor": "hover"}, "takes no --planner"),
        ({"family": "position"}, "apply to --task ood only"),
        ({"task": "ood", "ring": "2"}, "--ring needs --family"),
        (
            {"task": "maze", "planner": "single", "legs": "corridor"},
            "--legs corridor applies to --task maze with --planner graph",
        ),
        ({"task": "maze", "legs": "tunnel"}, "legs must be one of any, corridor"),
        ({"task": "ood", "planner": "graph", "waypoints_from": "data"}, "applies to --task maze with --planner graph"),
        ({"task": "maze", "waypoints_from": "states"}, "waypoints_from must be one of cells, data"),
    ):
        with pytest.raises(UserError, match=match) as e:
            check_options(EvalOptions(**options))
        assert "\n" not in str(e.value)
