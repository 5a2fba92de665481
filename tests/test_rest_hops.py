"""experiments/rest_hops.py: the rest test and the hop search on hand-made flights."""

import math

import numpy as np
from conftest import load_experiment

rest_hops = load_experiment("rest_hops")


def _state(px, py, speed=0.0, tilt=0.0):
    s = np.zeros(18)
    s[0], s[1], s[3] = px, py, speed
    c, n = math.cos(tilt), math.sin(tilt)
    s[6:15] = [c, 0, n, 0, 1, 0, -n, 0, c]  # a rotation about y by the tilt
    return s


def test_rest_needs_both_the_speed_and_the_tilt_within_the_goal_test():
    s = np.stack([_state(0, 0), _state(0, 0, speed=0.5), _state(0, 0, tilt=0.2), _state(0, 0, speed=0.3, tilt=0.1)])
    assert rest_hops.rest_mask(s).tolist() == [True, False, False, True]


def test_a_hop_counts_only_toward_a_later_rest_far_enough():
    xy = np.array([[0.0, 0.0], [0.5, 0.0], [2.4, 0.0], [2.5, 0.1]])
    assert rest_hops.hops_from(xy, 2.0).tolist() == [True, True, False, False]
    assert rest_hops.hops_from(xy[::-1], 2.0).tolist() == [True, True, False, False]
    assert not rest_hops.hops_from(xy, 3.0).any()
    many = np.concatenate([np.zeros((600, 2)), [[0.0, 2.0]]])  # past one block of rows
    assert rest_hops.hops_from(many, 2.0)[:600].all()


def test_a_folder_without_data_is_a_one_line_error(tmp_path, capsys):
    assert rest_hops.main([str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("rest_hops: error:") and "\n" not in err
