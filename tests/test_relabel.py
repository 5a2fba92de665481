"""Hindsight relabelling (thesis Alg. 2 line 4) on a hand-made dataset."""

import pytest
import torch

from aerohrl import task
from aerohrl.algorithms.data import GoalBatchSampler, fit_normalizer, load_dataset
from aerohrl.algorithms.relabel import FUTURE_STRATEGIES, relabel_goals, reward_done, sample_future_index

from aerohrl.algorithms.synthetic import straight_columns


def _data():
    return load_dataset(straight_columns(n_eps=5, length=[7, 12, 1, 20, 9], seed=1))


# every offset distribution of the relabelled goal (config: relabel_offset/_window/_mean_offset)
FUTURES = [
    {},
    {"strategy": "uniform", "window": 5},
    {"strategy": "geometric", "mean": 4.0},
    {"strategy": "geometric", "mean": 3.0, "window": 6},
    {"strategy": "geometric", "mean": 1.0},
]
FUTURE_IDS = ["uniform-rest", "uniform-w5", "geom-4", "geom-3-w6", "geom-1"]
SOME = [0, 1, 3]  # the default, a uniform window and a capped geometric offset (for the slower tests)


def test_episode_end_index():
    d = _data()
    ep = d.episode_index
    for i in range(len(d)):
        e = int(d.episode_end[i])
        assert ep[e] == ep[i] and (e == len(d) - 1 or ep[e + 1] != ep[i])


@pytest.mark.parametrize("future", FUTURES, ids=FUTURE_IDS)
def test_future_index_strictly_later_same_episode(future):
    d = _data()
    g = torch.Generator().manual_seed(0)
    idx = torch.arange(len(d)).repeat(200)
    k = sample_future_index(idx, d.episode_end[idx], g, **future)
    last = idx == d.episode_end[idx]
    assert (k[~last] > idx[~last]).all()
    assert (k[last] == idx[last]).all()
    assert (d.episode_index[k] == d.episode_index[idx]).all()
    if future.get("window"):
        assert (k - idx).max() <= future["window"]
    j = 20  # first frame of episode 3 (7+12+1): 20 frames, later steps 21..39
    if not future:  # every later step of an episode is reachable (uniform support)
        assert set(k[idx == j].tolist()) == set(range(21, 40))
    elif future == {"strategy": "uniform", "window": 5}:
        assert set(k[idx == j].tolist()) == set(range(21, 26))
    elif future["strategy"] == "geometric" and future["mean"] == 1.0:
        assert (k[~last] == idx[~last] + 1).all()  # mean 1: always the next step


def test_offset_distributions_match_their_parameters():
    d = load_dataset(straight_columns(n_eps=2, length=3000, seed=4))
    g = torch.Generator().manual_seed(7)
    idx = torch.randint(0, 1000, (200_000,), generator=g)  # >= 2000 steps before the end: no episode cap
    end = d.episode_end[idx]
    off = lambda **kw: (sample_future_index(idx, end, g, **kw) - idx).double()  # noqa: E731
    for mean in (5.0, 30.0, 80.0):  # geometric on 1, 2, ...: mean `mean`, P(offset = 1) = 1 / mean
        o = off(strategy="geometric", mean=mean)
        assert abs(o.mean().item() / mean - 1) < 0.02, (mean, o.mean())
        assert abs((o == 1).double().mean().item() - 1 / mean) < 0.01
    o = off(strategy="uniform", window=60)  # uniform on 1..60
    assert o.min() == 1 and o.max() == 60 and abs(o.mean().item() - 30.5) < 0.3
    counts = torch.bincount(o.long(), minlength=61)[1:].double()
    assert (counts / counts.mean() - 1).abs().max() < 0.1
    o = off(strategy="geometric", mean=30.0, window=45)  # capped: the overflow lands on 45
    assert o.max() == 45 and abs((o == 45).double().mean().item() - (1 - 1 / 30) ** 44) < 0.01
    # near the end of an episode the offset stops at its last step (strictly later, same episode)
    j = torch.full((10_000,), 2995)
    k = sample_future_index(j, d.episode_end[j], g, strategy="geometric", mean=30.0)
    assert k.min() >= 2996 and k.max() == 2999


def test_uniform_default_is_the_original_draw():
    """The default (uniform over the rest of the episode) keeps the draw it always had."""
    d = _data()
    idx = torch.arange(len(d)).repeat(50)
    span = (d.episode_end[idx] - idx).clamp_min(0)
    u = torch.rand(idx.shape, generator=torch.Generator().manual_seed(9))
    expect = torch.where(span > 0, idx + 1 + (u * span).long().clamp_max(span - 1), idx)
    assert torch.equal(sample_future_index(idx, d.episode_end[idx], torch.Generator().manual_seed(9)), expect)
    assert set(FUTURE_STRATEGIES) == {"uniform", "geometric"}


@pytest.mark.parametrize("future", FUTURES, ids=FUTURE_IDS)
def test_every_relabelled_goal_is_a_later_achieved_goal(future):
    d = _data()
    g = torch.Generator().manual_seed(3)
    idx = torch.randint(0, len(d), (5000,), generator=g)
    new, mask = relabel_goals(d.goal[idx], idx, d.episode_end[idx], d.achieved_goal, 0.6, g, **future)
    ag = d.achieved_goal
    w = future.get("window") or len(d)
    for i, gl in zip(idx[mask].tolist(), new[mask]):
        later = torch.arange(i + 1, min(int(d.episode_end[i]), i + w) + 1)
        assert later.numel() > 0
        assert (ag[later] == gl).all(-1).any(), "relabelled goal is not a later achieved goal of the episode"
    assert torch.equal(new[~mask], d.goal[idx][~mask])


@pytest.mark.parametrize("future", [FUTURES[i] for i in SOME], ids=[FUTURE_IDS[i] for i in SOME])
def test_relabel_rate_matches_delta(future):
    d = _data()
    g = torch.Generator().manual_seed(5)
    idx = torch.randint(0, len(d), (200_000,), generator=g)
    eligible = idx < d.episode_end[idx]
    for delta in (0.0, 0.3, 0.8, 1.0):
        _, mask = relabel_goals(d.goal[idx], idx, d.episode_end[idx], d.achieved_goal, delta, g, **future)
        rate = mask[eligible].float().mean().item()
        assert abs(rate - delta) < 0.005, (delta, rate)
        assert not mask[~eligible].any()


@pytest.mark.parametrize("future", [FUTURES[i] for i in SOME], ids=[FUTURE_IDS[i] for i in SOME])
def test_reward_and_done_recomputed_for_the_new_goal(future):
    d = load_dataset(straight_columns(n_eps=3, length=40, seed=2))
    norm = fit_normalizer(d, 0.5, future=future)
    s = GoalBatchSampler(d, norm, batch_size=4096, delta=0.7, generator=torch.Generator().manual_seed(0), future=future)
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


@pytest.mark.parametrize("augment", ["none", "mirror"])
def test_critic_random_goals_are_a_separate_batch(augment):
    """OGBench's value_p_randomgoal: the critics' goals are random achieved goals with
    probability p; the actor's batch is what it would be without the option."""
    d = load_dataset(straight_columns(n_eps=6, length=40, seed=3))
    norm = fit_normalizer(d, 0.5)

    def sampler(p):
        return GoalBatchSampler(
            d,
            norm,
            batch_size=8192,
            delta=0.3,
            generator=torch.Generator().manual_seed(4),
            mc_gamma=0.99,
            augment=augment,
            critic_random_goal_prob=p,
        )

    plain, both = sampler(0.0).sample(), sampler(0.4).sample()
    assert "critic" not in plain.keys()
    if augment == "none":  # the critics' draws come after the actor's: same actor batch
        assert torch.equal(plain["observation"], both["observation"]) and torch.equal(plain["goal"], both["goal"])
    c = both["critic"]
    assert torch.equal(c["state"], both["state"]) and torch.equal(c["action"], both["action"])
    changed = (c["goal"] != both["goal"]).any(-1)
    assert abs(changed.float().mean().item() - 0.4) < 0.03  # a random frame's own goal may coincide, rarely
    # every critic goal is the actor's or an achieved goal of the (mirrored) data
    r_expect = task.goal_reached(task.achieved_goal(c["next_state"]), c["goal"])
    assert torch.equal(c["next", "reward"].squeeze(-1), r_expect.float())
    o, rel = task.policy_inputs(c["state"], c["goal"])
    assert torch.allclose(c["observation"], (torch.cat([o, rel], -1) - norm.in_mean) / norm.in_std)
    # the data's observed return for a random goal is only its immediate reward
    lb = c["mc_lower_bound"].squeeze(-1)
    assert torch.equal(lb[changed], c["next", "reward"].squeeze(-1)[changed])
    same = lb[~changed] == both["mc_lower_bound"].squeeze(-1)[~changed]  # (a random draw of the same goal: its reward)
    assert (same | (lb[~changed] == c["next", "reward"].squeeze(-1)[~changed])).all() and same.float().mean() > 0.95
