"""Hindsight relabelling (thesis Alg. 2 line 4) on a hand-made dataset."""

import torch

from aerohrl import task
from aerohrl.algorithms.data import GoalBatchSampler, fit_normalizer, load_dataset
from aerohrl.algorithms.relabel import relabel_goals, reward_done, sample_future_index

from aerohrl.algorithms.synthetic import straight_columns


def _data():
    return load_dataset(straight_columns(n_eps=5, length=[7, 12, 1, 20, 9], seed=1))


def test_episode_end_index():
    d = _data()
    ep = d.episode_index
    for i in range(len(d)):
        e = int(d.episode_end[i])
        assert ep[e] == ep[i] and (e == len(d) - 1 or ep[e + 1] != ep[i])


def test_future_index_strictly_later_same_episode():
    d = _data()
    g = torch.Generator().manual_seed(0)
    idx = torch.arange(len(d)).repeat(200)
    k = sample_future_index(idx, d.episode_end[idx], g)
    last = idx == d.episode_end[idx]
    assert (k[~last] > idx[~last]).all()
    assert (k[last] == idx[last]).all()
    assert (d.episode_index[k] == d.episode_index[idx]).all()
    # every later step of an episode is reachable (uniform support)
    j = 20  # first frame of episode 3 (7+12+1): 20 frames, later steps 21..39
    assert set(k[idx == j].tolist()) == set(range(21, 40))


def test_every_relabelled_goal_is_a_later_achieved_goal():
    d = _data()
    g = torch.Generator().manual_seed(3)
    idx = torch.randint(0, len(d), (5000,), generator=g)
    new, mask = relabel_goals(d.goal[idx], idx, d.episode_end[idx], d.achieved_goal, 0.6, g)
    ag = d.achieved_goal
    for i, gl in zip(idx[mask].tolist(), new[mask]):
        later = torch.arange(i + 1, int(d.episode_end[i]) + 1)
        assert later.numel() > 0
        assert (ag[later] == gl).all(-1).any(), "relabelled goal is not a later achieved goal of the episode"
    assert torch.equal(new[~mask], d.goal[idx][~mask])


def test_relabel_rate_matches_delta():
    d = _data()
    g = torch.Generator().manual_seed(5)
    idx = torch.randint(0, len(d), (200_000,), generator=g)
    eligible = idx < d.episode_end[idx]
    for delta in (0.0, 0.3, 0.8, 1.0):
        _, mask = relabel_goals(d.goal[idx], idx, d.episode_end[idx], d.achieved_goal, delta, g)
        rate = mask[eligible].float().mean().item()
        assert abs(rate - delta) < 0.005, (delta, rate)
        assert not mask[~eligible].any()


def test_reward_and_done_recomputed_for_the_new_goal():
    d = load_dataset(straight_columns(n_eps=3, length=40, seed=2))
    norm = fit_normalizer(d, 0.5)
    s = GoalBatchSampler(d, norm, batch_size=4096, delta=0.7, generator=torch.Generator().manual_seed(0))
    b = s.sample()
    r_expect = task.goal_reached(task.achieved_goal(b["next_state"]), b["goal"])
    assert torch.equal(b["next", "reward"].squeeze(-1), r_expect.float())
    assert torch.equal(b["next", "done"].squeeze(-1), r_expect)
    assert torch.equal(b["next", "terminated"], b["next", "done"])
    # relabelled goals one or two steps ahead are reached (straight lines, 1.5 m/s max):
    # there must be positive rewards among relabelled transitions, none for far desired goals
    assert b["next", "reward"][b["relabelled"]].sum() > 0
    r, dn = reward_done(b["next_state"], b["goal"])
    assert torch.equal(r.bool(), dn)
    # the normalised inputs are the task's translation-invariant inputs
    o, rel = task.policy_inputs(b["state"], b["goal"])
    x = (torch.cat([o, rel], -1) - norm.in_mean) / norm.in_std
    assert torch.allclose(b["observation"], x)
    o2, rel2 = task.policy_inputs(b["next_state"], b["goal"])
    assert torch.allclose(b["next", "observation"], (torch.cat([o2, rel2], -1) - norm.in_mean) / norm.in_std)


def test_buffer_indices_are_dataset_rows():
    d = _data()
    norm = fit_normalizer(d, 0.5)
    s = GoalBatchSampler(d, norm, batch_size=64, delta=0.0, generator=torch.Generator().manual_seed(0))
    b = s.buffer.sample()
    assert torch.equal(b["state"], d.state[b["index"]])
    assert torch.equal(b["episode_end"], d.episode_end[b["index"]])
