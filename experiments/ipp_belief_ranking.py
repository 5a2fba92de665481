"""How well learned target beliefs rank the cells a search has not sensed yet, beside the
world generator's own target probability (the "oracle" no planner has).

    python experiments/ipp_belief_ranking.py runs/ipp/belief-s7 runs/ipp/belief-big-s7 [-o table.md]

On the validation states of the first run (every run must hold the same validation worlds),
per belief: the log-loss over all cells and over the never-sensed ones, and, over the
never-sensed cells of each state that still hide a target, the ranking figures a search
acts on: the AUC (the chance that a target cell scores above an empty one) and the share of
those targets in the top 10 % of the cells. Rows: each learned belief (its calibrated
temperature, as ``ipp bench --belief`` uses it), the hand-written posterior, the prior, and
the generator's marginal ``1 - (1 - density)^n_targets`` (targets are drawn without
replacement from the true density: the marginal to first order), which knows the true
cluster centres that the prior shifts.

A search that ranks cells by expected detections is nearly blind to a monotone rescaling of
the belief, so log-loss (which rewards the scale) and ranking can disagree; this script
shows by how much.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from aerohrl.errors import ArgumentParser, UserError, run_cli
from aerohrl.ipp.belief import log_loss

PROG = "experiments/ipp_belief_ranking.py"
TOP = 0.10  # the share of never-sensed cells counted as a search's first choices
LOGLOSS_EPS = 1e-6  # probabilities clipped to [eps, 1 - eps]: the oracle's marginal reaches 0


def _auc(score: np.ndarray, y: np.ndarray) -> float:
    """Mann-Whitney AUC of ``score`` for the positives ``y`` (ties counted half)."""
    from scipy.stats import rankdata

    n1 = int(y.sum())
    n0 = len(y) - n1
    r = rankdata(score)
    return float((r[y].sum() - n1 * (n1 + 1) / 2) / (n1 * n0))


def beliefs(runs: list[Path]) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]:
    """``{row: q (k, S, S)}`` on the first run's validation states, their targets (k, S, S)
    and never-sensed masks (k, S, S)."""
    import torch

    from aerohrl.ipp.belief import load_belief, load_data, logits_over, read_belief_config
    from aerohrl.ipp.sensor import sigmoid
    from aerohrl.ipp.factory import sample_for

    torch.set_num_threads(1)
    cfg0 = read_belief_config(runs[0])
    _, val = load_data(runs[0] / "data.npz")
    y = val.targets[val.world]
    rows: dict[str, np.ndarray] = {}
    for run in runs:
        _, v = load_data(run / "data.npz")
        if not np.array_equal(v.seeds, val.seeds):
            raise UserError(f"{run}: its validation worlds differ from {runs[0]}'s (same --val-seed and --val-worlds needed)")
        model = load_belief(run / "belief.pt")  # the calibrated temperature, as ipp bench --belief
        z, base = logits_over(model, val)
        rows[f"learned: {run.name} (T = {model.temperature:.3f})"] = sigmoid(z / model.temperature)
    rows["hand-written posterior"] = sigmoid(base)
    rows["prior"] = val.prior[val.world].astype(np.float64)
    worlds = sample_for(cfg0.env, int(val.seeds[0, 0]), val.seeds[:, 1])
    n_t = worlds.targets.reshape(len(worlds.targets), -1).sum(1)
    oracle = 1 - (1 - worlds.density) ** n_t[:, None, None]
    if not np.array_equal(worlds.targets, val.targets):
        raise UserError(f"{runs[0]}: the validation worlds do not regenerate (another world config?)")
    rows["generator's marginal (oracle)"] = oracle[val.world]
    return rows, y, ~val.cov


def table(rows: dict[str, np.ndarray], y: np.ndarray, unsensed: np.ndarray) -> str:
    """The Markdown table of every row's figures."""
    keep = [t for t in range(len(y)) if y[t][unsensed[t]].any() and unsensed[t].sum() >= 20]
    out = [
        f"Validation states: {len(y):,} ({len(keep):,} with a target in a never-sensed cell); target rate {y.mean():.4f}.",
        "",
        "| belief | log-loss | log-loss, never-sensed | AUC, never-sensed | targets in the top 10 % of never-sensed cells |",
        "|---|---|---|---|---|",
    ]
    for name, q in rows.items():
        aucs, tops = [], []
        for t in keep:
            m = unsensed[t]
            s, yy = q[t][m], y[t][m]
            aucs.append(_auc(s, yy))
            k = max(1, int(TOP * m.sum()))
            tops.append(yy[np.argsort(-s, kind="stable")[:k]].sum() / yy.sum())
        out.append(
            f"| {name} | {log_loss(q, y, eps=LOGLOSS_EPS):.4f} | {log_loss(q[unsensed], y[unsensed], eps=LOGLOSS_EPS):.4f} | "
            f"{np.mean(aucs):.3f} | {np.mean(tops):.3f} |"
        )
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Print (and with ``-o`` write) the ranking table of the given belief runs; exit code."""
    ap = ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", type=Path, help="learned-belief runs (aerohrl ipp belief train -o RUN)")
    ap.add_argument("-o", "--out", type=Path, help="also write the table to this Markdown file")
    a = ap.parse_args(argv)

    def go() -> int:
        for r in a.runs:
            if not (r / "belief.pt").is_file() or not (r / "data.npz").is_file():
                raise UserError(f"{r}: not a learned-belief run (no belief.pt and data.npz)")
        text = table(*beliefs(a.runs))
        sys.stdout.write(text)
        if a.out is not None:
            from aerohrl.atomic import write_text

            write_text(a.out, text)
        return 0

    return run_cli(PROG, go)


if __name__ == "__main__":
    sys.exit(main())
