"""REPORT.md from the computed evaluation: verdicts, method, claims, layouts, horizons, who decides, lags."""

from __future__ import annotations

from experiments.conditions import RANDOM_TAXI
from experiments.claims import AGENT_NAMES, MARGIN, METRICS
from experiments.declarations import of_run
from experiments.report_claims import claim_section, iv as _iv, method_lines, verdict_table
from experiments.report_runs import method_lines as declared_method_lines, settlement_lines


def panel_lines(name: str, title: str, figure: str, panels: dict, hz: dict) -> list[str]:
    lines = [
        f"### {title} (`{name}`)",
        "",
        f"![{name}]({name}.png)",
        "",
        f"{hz['episodes']} episodes; {figure}. "
        f"Best arm at the end: {AGENT_NAMES.get(hz['best_arm'], hz['best_arm'])}, "
        f"its mean ln steps changed by {hz['change_last']:+.3f} over the last {hz['window']} episodes "
        f"({'flat' if hz['flat'] else 'NOT flat'}; flat means |change| < {MARGIN:.3f}).",
        "",
    ]
    for subset, rows in panels.items():
        lines += [
            f"{subset} layouts:",
            "",
            "| arm | trials | mean ln steps | ln steps, last 10 | success rate | mean return | alpha_h end "
            "| H decides |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for arm, r in rows.items():
            ah = f"{r['alpha_h_end']:.2f}" if "alpha_h_end" in r and r.get("h_decides_share") is not None else ""
            hd = f"{r['h_decides_share']:.1%}" if r.get("h_decides_share") is not None else ""
            lines.append(
                f"| {AGENT_NAMES.get(arm, arm)} | {r['trials']} | {_iv(r['ln_steps'], 2)} | "
                f"{_iv(r['ln_steps_last10'], 2)} | {_iv(r['success'], 2)} | {_iv(r['return'], 2)} | "
                f"{ah} | {hd} |"
            )
        lines.append("")
    return lines


def layouts_lines(drawn: dict, scale: dict | None = None) -> list[str]:
    """The maze layouts the run used (from its scale: `layouts` from `first_layout` on), how many of each kind,
    and how often the generator's stream drew a misleading one up to them. `drawn`: the stream's draws for the
    first 180 layouts, for a run that recorded no scale."""
    from common.envs.maze import LAYOUT_COUNT, layout_pool

    first = int((scale or {}).get("first_layout", 0))
    end = min(first + int((scale or {}).get("layouts", 180)), LAYOUT_COUNT)
    if scale:
        pool, drawn = layout_pool(end + end % 2)
        pool = pool[first:end]
    else:
        pool, _ = layout_pool()
    total = sum(drawn.values())
    mis = [
        f"{L.index} (shortest path {L.shortest_path()}, dead end at {', '.join(map(str, L.misleading_dead_ends()))})"
        for L in pool
        if L.kind == "misleading"
    ]
    return [
        "## Layouts",
        "",
        f"{len(pool)} layouts ({pool[0].index}-{pool[-1].index}), {sum(L.kind == 'honest' for L in pool)} honest "
        f"(even indices) and {sum(L.kind == 'misleading' for L in pool)} misleading (odd indices), drawn from one "
        f"stream (`common/envs/maze.py`): of its first {total} distinct solvable draws (up to layout "
        f"{pool[-1].index}) {drawn.get('misleading', 0)} ({drawn.get('misleading', 0) / max(total, 1):.0%}) were "
        "misleading for the paper's Manhattan rule (an agent taking only the moves the rule approves can reach a "
        "dead end). Misleading layouts: " + "; ".join(mis[:8]) + ("; ..." if len(mis) > 8 else "") + ".",
        "",
    ]


def horizon_lines(result: dict, conds) -> list[str]:
    lines = [
        "## Horizons",
        "",
        "DQN converged: its curve flat over the last 20 episodes and its final geometric-mean "
        "episode below 100 steps (a tenth of the step limit). Steps to its level: mean environment steps of a "
        "DQN trial up to the episode at which its curve (5-episode moving average) first comes within the "
        "margin of its final level.",
        "",
        "| condition | episodes | best arm | change of its mean ln steps, last 20 | flat | "
        "DQN within the margin of its final level from episode | steps to that level | DQN final steps "
        "(geo. mean) | DQN converged | DQN steps per trial |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c in conds:
        h = result["horizons"][c.name]
        to = h.get("dqn_steps_to_level_mean")
        dq = (
            (
                f"{h.get('dqn_within_margin_episode') or 'never'} | {f'{to:,.0f}' if to else ''} | "
                f"{h['dqn_final_steps_geomean']:.0f} | {'yes' if h.get('dqn_converged') else 'no'} | "
                f"{h['dqn_steps_total_mean']:,.0f}"
            )
            if "dqn_final_steps_geomean" in h
            else " | | | | "
        )
        lines.append(
            f"| {c.name} | {h['episodes']} | {AGENT_NAMES.get(h['best_arm'], h['best_arm'])} | "
            f"{h['change_last']:+.3f} | {'yes' if h['flat'] else 'no'} | {dq} |"
        )
    return lines + [""]


def who_lines(result: dict) -> list[str]:
    lines = [
        "## Who decides: alpha_h and H against Q",
        "",
        "![who decides](who-decides.png)",
        "",
        "alpha_h at the end of the run and the share of greedy actions where argmax(alpha_q Q + alpha_h H) "
        "differs from argmax Q (H decided against Q), over the whole run:",
        "",
        "| condition | arm | layouts | alpha_h end | H decides (whole run) | H decides (last 10 episodes) |",
        "|---|---|---|---|---|---|",
    ]
    for cond, arms in result["who_decides"].items():
        for arm, by in arms.items():
            for subset, d in by.items():
                share = [x for x in d["h_decides"] if x == x]
                last = [x for x in d["h_decides"][-10:] if x == x]
                lines.append(
                    f"| {cond} | {AGENT_NAMES.get(arm, arm)} | {subset} | {d['alpha_h'][-1]:.2f} | "
                    f"{(sum(share) / len(share) if share else float('nan')):.1%} | "
                    f"{(sum(last) / len(last) if last else float('nan')):.1%} |"
                )
    return lines + [""]


def lag_lines(result: dict) -> list[str]:
    if not result["learned_lags"]:
        return []
    lines = [
        "## Learned delay (beyond the paper)",
        "",
        "![learned lags](learned-lags.png)",
        "",
        "The learner's candidate lags are 0..6 steps; `uniform` assumes them equally likely, `true` uses the "
        "observer's distribution (a drifting observer: its average), `learned` starts uniform and follows "
        "online EM (`common/core/delay_model.py`). Honest layouts only, high frequency.",
        "",
        "| condition | true mean lag (start -> end) | learned mean lag at the end |",
        "|---|---|---|",
    ]
    for cond, d in result["learned_lags"].items():
        learned = ", ".join(f"{AGENT_NAMES.get(a, a)} {v[-1]:.2f}" for a, v in d["learned"].items())
        lines.append(f"| {cond} | {d['true'][0]:.2f} -> {d['true'][-1]:.2f} | {learned} |")
    return lines + [""]


def machines_lines(out: str, timing: dict) -> list[str]:
    import json
    import os

    path = os.path.join(out, "machines.json")
    if not os.path.exists(path):
        return [
            "## Across machines",
            "",
            "(no comparison recorded: `python -m experiments machines DIR_A DIR_B` "
            "compares two runs' trials and verdicts)",
            "",
        ]
    m = json.load(open(path))
    stale = m.get("scale") != timing.get("scale") or m.get("commit") is None
    note = (
        f" (Compared at commit `{m.get('commit', '?')}` on a run of scale {m.get('scale')}: "
        "NOT this report's trials; re-run the comparison: "
        'docs/notes/2026-11-23-reproduction-pilots-and-speed.md, "Across machines".)'
        if stale
        else f" (Compared at commit `{m.get('commit')}`, this report's scale.)"
    )
    lines = [
        "## Across machines (BLAS code path)",
        "",
        m["summary"] + note,
        "",
        "| condition | arm | trials | trials that differ |",
        "|---|---|---|---|",
    ]
    for row in m["rows"]:
        lines.append(f"| {row['cond']} | {row['arm']} | {row['trials']} | {row['differ']} |")
    return lines + [""]


def _run_figures(t: dict) -> str:
    per_worker = t.get("cpu_s_per_worker") or {}
    cpu = sum(per_worker.values())
    split = f" ({' + '.join(f'{v:.0f}' for v in per_worker.values())})" if len(per_worker) > 1 else ""
    peak = f", up to {t['load_average_max']:.1f} during the run" if t.get("load_average_max") is not None else ""
    spread = (
        f"; the workers finished their last jobs {t['worker_end_spread_s']:.0f} s apart"
        if t.get("worker_end_spread_s") is not None
        else ""
    )
    m = t.get("machine") or {}
    where = f" ({m['cpu_model']}, {m['cores_usable']} usable)" if m else ""
    return (
        f"wall {t['total_s']:.0f} s ({t['total_s'] / 60:.1f} min) on {t['workers']} worker process(es) and "
        f"{t.get('cpus', '?')} CPUs{where}, {cpu:.0f} CPU s in the workers{split}, {t.get('trial_steps', 0):,} "
        f"environment steps, load average {t.get('load_average_at_start', [0])[0]:.1f} at the start{peak} and "
        f"{t.get('load_average_at_end', [0])[0]:.1f} at the end (1-minute averages; a machine shared with other "
        f"jobs){spread}"
    )


def timing_sentence(timing: dict) -> str:
    """This run's cost, and whether its trials came from the cache; the last from-scratch run's cost."""
    n, computed = timing["trials"], timing["trials_computed"]
    if timing.get("from_scratch"):
        return (
            f"From scratch (empty trial cache, every one of {n} trial results simulated or shared; started "
            f"{timing.get('started_utc', '?')}): {_run_figures(timing)}."
        )
    now = (
        f"This run simulated {computed} of {n} trial results and read {timing['trials_cached']} from the trial "
        f"cache (NOT a from-scratch timing): {_run_figures(timing)}."
    )
    last = timing.get("last_from_scratch")
    if not last:
        return now + " No from-scratch run of this report is recorded."
    same = last.get("scale") == timing.get("scale")
    return now + (
        f" The last from-scratch run (commit `{last.get('commit', '?')}`, started "
        f"{last.get('started_utc', '?')}{'' if same else ', ANOTHER scale: ' + str(last.get('scale'))}): "
        f"{_run_figures(last)}."
    )


def taxi_scale(sc: dict, conds) -> str:
    """The Taxi trials this report holds, by variant (either may be left out of a run)."""
    parts = []
    if any(c.is_taxi and c.env in RANDOM_TAXI for c in conds):
        parts.append(
            f"{sc.get('taxi_trials', '?')} trials of Gymnasium's Taxi x "
            f"{sc.get('taxi_random_episodes', sc.get('taxi_episodes', '?'))} episodes"
        )
    if any(c.is_taxi and c.env not in RANDOM_TAXI for c in conds):
        parts.append(
            f"{sc.get('taxi_fixed_trials', sc.get('taxi_trials', '?'))} trials of the fixed-task Taxi x "
            f"{sc.get('taxi_episodes', '?')} episodes"
        )
    else:
        parts.append("no fixed-task Taxi (run only when named: `--only taxi-fixed-stop`)")
    return " and ".join(parts) if any(c.is_taxi for c in conds) else "no Taxi"


def body(
    result: dict, conds, timing: dict, argv: list[str], drawn: dict, out: str, settle: list[dict] | None = None
) -> list[str]:
    claims, prev = result["claims"], result.get("previous", {})
    decl = of_run(result)
    declared_in = "`experiments/claims.py`" if decl.module == "experiments/claims.py" else f"`{decl.module}`"
    sc = timing.get("scale", {})
    lines = [
        "# Reproduction of the paper's claims (generated)",
        "",
        f"Generated by `python -m experiments {' '.join(argv)}` at commit `{timing.get('commit', '?')}`: "
        f"{sc.get('layouts', '?')} maze layouts x {sc.get('reps', '?')} seed(s), {sc.get('maze_episodes', '?')} "
        f"maze episodes, "
        + taxi_scale(sc, conds)
        + ". "
        + timing_sentence(timing)
        + " Every verdict is computed by `experiments/evaluate.py` from the tests "
        f"declared in {declared_in}; nothing here is written by hand.",
        "",
        "## Verdicts: the paper's claims (one Holm family)",
        "",
    ]
    lines += verdict_table(claims, "paper", prev, decl.deciding)
    lines += ["", "## Verdicts: beyond the paper (its own Holm family)", ""]
    lines += verdict_table(claims, "beyond", prev, decl.deciding) + [""]
    lines += settlement_lines(settle) if settle else []
    lines += method_lines(result) if decl.deciding == METRICS else declared_method_lines(decl, result)
    lines += ["## Claims", ""]
    for cid, c in claims.items():
        lines += claim_section(cid, c, decl.deciding)
    lines += layouts_lines(drawn, timing.get("scale")) + horizon_lines(result, conds)
    lines += who_lines(result) + lag_lines(result)
    lines += machines_lines(out, timing) + ["## Conditions", ""]
    for c in conds:
        lines += panel_lines(c.name, c.title, c.figure, result["panels"][c.name], result["horizons"][c.name])
    cpu = ", ".join(f"{v:.0f}" for v in timing.get("cpu_s_per_worker", {}).values())
    lines += [
        "## Timing",
        "",
        f"This run: wall {timing['total_s']:.1f} s for {timing['trials']} trial results: "
        f"{timing['trials_computed']} simulated ({timing.get('trial_steps', 0):,} environment steps), "
        f"{timing['trials_shared']} shared between conditions (an agent that ignores feedback is the same "
        f"under every observer), {timing['trials_cached']} read from the cache. CPU seconds per worker: {cpu}. "
        f"BLAS/threads environment: {timing.get('env')}.",
        "",
    ]
    return lines
