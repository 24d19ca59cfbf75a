"""Per-condition panels (honest, misleading, pooled layouts), horizons, and who decides (alpha_h, H vs Q)."""

from __future__ import annotations

import numpy as np

from experiments import stats
from experiments.claims import MARGIN
from experiments.evaluate import SUBSETS, ArmData, subset_mask

FLAT_WINDOW = 20
CONVERGED_STEPS = 100.0
"""DQN has converged when its curve is flat and its final geometric-mean episode is below this: a tenth of
the 1000-step limit of Maze and Taxi (their optima are 5-15 and about 13 steps, plus epsilon's detours)."""


def arm_summary(a: ArmData, extras: dict, mask: np.ndarray, n_boot: int) -> dict:
    """Mean ln steps (all episodes, last 10), success rate, mean return, with layout-bootstrap intervals;
    alpha_h at the end and the share of greedy actions H decided against Q."""
    st, ret, cl = a.steps[mask], a.returns[mask], a.clusters[mask]
    max_steps = 1000
    out = {"trials": int(mask.sum()), "layouts": int(len(np.unique(cl)))}
    per_trial = {
        "ln_steps": stats.log_steps(st).mean(axis=1),
        "ln_steps_last10": stats.log_steps(st[:, -10:]).mean(axis=1),
        "success": (st < max_steps).mean(axis=1),
        "return": ret.mean(axis=1),
    }
    for name, v in per_trial.items():
        b = stats.cluster_bootstrap(v, cl, n_boot)
        out[name] = {"estimate": b["estimate"], "ci": b["ci"]}
    alpha = extras.get("alpha_h")
    if alpha is not None:
        out["alpha_h_end"] = float(np.mean(alpha[mask][:, -1]))
    decided, greedy = extras.get("h_decided"), extras.get("greedy")
    if decided is not None and greedy[mask].sum() > 0:
        out["h_decides_share"] = float(decided[mask].sum() / greedy[mask].sum())
    lag = extras.get("mean_lag")
    if lag is not None:
        out["mean_lag_end"] = float(np.mean(lag[mask][:, -1]))
    return out


def condition_panels(arms: dict[str, ArmData], extras: dict[str, dict], n_boot: int) -> dict:
    """subset -> arm -> summary, for the subsets that apply (taxi and honest-only conditions: fewer)."""
    out: dict = {}
    for subset in SUBSETS:
        rows = {}
        for arm, a in arms.items():
            mask = subset_mask(a, subset)
            if mask is None or mask.sum() < 2:
                continue
            if subset == "pooled" or not mask.all():
                rows[arm] = arm_summary(a, extras.get(arm, {}), mask, n_boot)
        if rows:
            out[subset] = rows
    return out


def horizon(arms: dict[str, ArmData], stop: int | None) -> dict:
    """Is the best arm's curve flat at the end? Change of its mean ln steps over the last FLAT_WINDOW
    episodes (linear fit, scipy.stats.linregress), flat when below MARGIN. For DQN: episodes until its
    mean ln-steps curve (5-episode moving average) first comes within MARGIN of its final level."""
    from scipy import stats as sps  # (here: scipy.stats takes a second to import, and most commands never fit)

    curves = {arm: stats.log_steps(a.steps).mean(axis=0) for arm, a in arms.items()}
    E = len(next(iter(curves.values())))
    best = min(curves, key=lambda k: curves[k][-10:].mean())
    w = min(FLAT_WINDOW, E)
    fit = sps.linregress(np.arange(w), curves[best][-w:])
    out = {
        "episodes": E,
        "best_arm": best,
        "change_last": float(fit.slope * (w - 1)),
        "window": w,
        "flat": bool(abs(fit.slope * (w - 1)) < MARGIN),
    }
    if "dqn" in arms:
        c = curves["dqn"]
        ma = np.convolve(c, np.ones(5) / 5, mode="valid")
        final = c[-10:].mean()
        hit = np.nonzero(ma <= final + MARGIN)[0]
        out["dqn_within_margin_episode"] = int(hit[0] + 5) if len(hit) else None
        out["dqn_final_steps_geomean"] = float(np.exp(final))
        out["dqn_steps_total_mean"] = float(arms["dqn"].steps.sum(axis=1).mean())
        at = out["dqn_within_margin_episode"]  # mean environment steps a DQN trial took to get there
        out["dqn_steps_to_level_mean"] = float(arms["dqn"].steps[:, :at].sum(axis=1).mean()) if at else None
        dfit = sps.linregress(np.arange(w), c[-w:])
        out["dqn_change_last"] = float(dfit.slope * (w - 1))
        out["dqn_flat"] = bool(abs(dfit.slope * (w - 1)) < MARGIN)
        # Converged: flat at the end, at a level far below the step limit (a flat curve of 1000-step
        # episodes is a failure to learn, not convergence).
        out["dqn_converged"] = bool(out["dqn_flat"] and np.exp(final) < CONVERGED_STEPS)
    return out


def who_decides_curves(arms: dict[str, ArmData], extras: dict[str, dict]) -> dict:
    """Per arm with H and Q and per subset: alpha_h per episode and the share of greedy actions that H
    decided against Q per episode (means over trials)."""
    out: dict = {}
    for arm, ex in extras.items():
        if "alpha_h" not in ex or ex["greedy"].sum() == 0:
            continue
        a = arms[arm]
        for subset in SUBSETS:
            mask = subset_mask(a, subset)
            if mask is None or mask.sum() == 0:
                continue
            g = ex["greedy"][mask].sum(axis=0)
            share = np.divide(ex["h_decided"][mask].sum(axis=0), g, out=np.full(len(g), np.nan), where=g > 0)
            out.setdefault(arm, {})[subset] = {
                "alpha_h": ex["alpha_h"][mask].mean(axis=0).tolist(),
                "h_decides": share.tolist(),
            }
    return out
