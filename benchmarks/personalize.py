"""A new driver from a few lane changes: the learning curve of personalisation.

Leave one driver out: the other drivers are the population; the held-out
driver's last session(s) are scored; its first K decisions of the earlier
sessions (K = 5, 10, 20 and all) are what it has shown. Policies side by side
(`benchmarks/personalize_curve.py`): the personalised agent (one column per variant), the
style agent (style assigned from the K decisions), the population agent, a DQN
from scratch on the K decisions, the imitation classifier on the K decisions and
on population + K, and the driver's own agent on all its earlier sessions (the
ceiling). Balanced accuracy, recall and timing error with bootstrap 95 %
intervals (`rl.evaluation.crossval.bootstrap_scores`, decisions resampled), per K,
pooled over drivers and per style (the full analysis's); then the issue's
acceptance lines (for the first variant, then for each other as if it were the
headline). Writes curve.json, curve.csv and curve.html (Plotly) to --out, and the table, the styles
assigned and the acceptance lines to `benchmarks/results/personalize.json` (`--result NAME`) with the
command, commit, date and machine.

Run on an analysed workspace (`laneprint ingest sample_logs -w WS && laneprint analyze -w WS`):

    python benchmarks/personalize.py -w WS [--drivers all|N|D01,D02] [--k 5,10,20,all]
        [--episodes N] [--variants none:blend,none:fit,...] [--observation O] [--jobs 2] [--seed 0] [--out DIR]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
import zlib
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from laneprint.workspace import Workspace  # noqa: E402
from rl.evaluation.crossval import bootstrap_scores  # noqa: E402
from rl.personalize.agents import PersonalizeSettings  # noqa: E402
from personalize_curve import ALL, CurveSettings, driver_curve  # noqa: E402  (beside this file)
from results_file import write_result  # noqa: E402  (beside this file)
from clustering.pipeline import stored_settings  # noqa: E402
from rl.problem.env import formulation_config  # noqa: E402
from rl.problem.rewards import ReferenceLines  # noqa: E402
from rl.settings import OBSERVATIONS, DQNSettings, resolve_formulation  # noqa: E402

#: The K-decision policies the personalised agent must match (the issue's list).
RIVALS = ("style", "scratch", "imitation_k", "imitation_pop_k")


def parse_variants(spec: str) -> dict[str, PersonalizeSettings]:
    """'finetune:style,finetune:population:min_episodes=2000;eps_start=0.3' -> {'personalised': ...,
    'personalised[finetune/population min_episodes=2000 eps_start=0.3]': ...} (the first is the headline).

    Each variant is METHOD:BASE, then optionally ':' and `PersonalizeSettings` fields as NAME=VALUE;...
    (METHOD: none, finetune, unsure (fine-tune when the style's confidence is below min_confidence), mix, own;
    BASE: fit, style, population, auto, blend (every style's agent and the population's, their advantages
    weighted: blend_prior=share|equal, blend_population, blend_fit_power)).
    """
    out = {}
    for i, part in enumerate(p for p in spec.split(",") if p):
        method, _, rest = part.partition(":")
        base, _, opts = rest.partition(":")
        fields = {f.name: f.type for f in dataclasses.fields(PersonalizeSettings)}
        extra: dict[str, Any] = {}
        for opt in (o for o in opts.split(";") if o):
            key, _, value = opt.partition("=")
            if key not in fields:
                raise SystemExit(f"--variants: no setting {key!r} (settings: {', '.join(fields)})")
            extra[key] = {"int": int, "float": float}.get(str(fields[key]), str)(value)
        label = f"{method}/{base or 'population'}" + "".join(f" {o}" for o in opts.split(";") if o)
        out["personalised" if i == 0 else f"personalised[{label}]"] = PersonalizeSettings(
            method=method, base=base or "population", **extra
        )
    return out


def one_driver(args: tuple) -> dict[str, Any]:
    """One held-out driver's curve (a process of its own with --jobs)."""
    ws_root, driver, others, episodes, seed, ks, variants, test_sessions, obs = args
    ws = Workspace(ws_root)
    decisions = ws.read_table("analysis", "decisions")
    # the lines feed no policy scored here; the observation is the 'decisions' reward's default unless named
    env = formulation_config(ReferenceLines.paper("Normal"), "decisions", observation=obs)
    dqn = DQNSettings(seed=seed, **({"episodes": episodes} if episodes else {}))
    t0 = time.perf_counter()
    res = driver_curve(
        decisions,
        driver,
        others,
        env,
        dqn,
        CurveSettings(ks=ks, test_sessions=test_sessions, seed=seed, variants=variants),
        stored_settings(ws),
    )
    res["wall_s"] = time.perf_counter() - t0
    return res


def scores(
    states: pd.DataFrame, changes: pd.DataFrame, policies: list[str], n_boot: int, seed: int
) -> list[dict[str, Any]]:
    """bootstrap_scores of every policy present in `states` (each its own seeded resamples)."""
    out = []
    for who in policies:
        rng = np.random.default_rng([seed, 11, zlib.crc32(who.encode())])
        col = f"action_{who}"
        if col not in states or states[col].isna().all():
            continue
        s = states[states[col].notna()].copy()
        s[col] = s[col].astype(int)
        out.append(bootstrap_scores(s, changes, who, n_boot, rng))
    return out


def table(results: pd.DataFrame, policies: list[str], n_boot: int, seed: int, group: str = "pooled") -> pd.DataFrame:
    """One row per (K, policy): balanced accuracy, recall, timing error with their intervals."""
    states, changes = results.attrs["states"], results.attrs["changes"]
    rows = []
    for k in dict.fromkeys(states["k"]):
        s, c = states[states["k"] == k], changes[changes["k"] == k]
        for r in scores(s, c, policies, n_boot, seed):
            rows.append(
                {
                    "group": group,
                    "k": k,
                    "policy": r["who"],
                    "n_decisions": r["n_decisions"],
                    "balanced_accuracy": r["balanced_accuracy"],
                    "ba_lo": r["balanced_accuracy_ci"][0],
                    "ba_hi": r["balanced_accuracy_ci"][1],
                    "recall": r["recall"],
                    "timing_mae_s": r["timing_mae_s"],
                    "timing_lo": (r["timing_mae_ci"] or [None, None])[0],
                    "timing_hi": (r["timing_mae_ci"] or [None, None])[1],
                }
            )
    ceiling = [r for r in rows if r["policy"] == "ceiling"]
    if ceiling:  # the driver's own full-data agent does not depend on K: shown at every K
        for k in dict.fromkeys(states["k"]):
            if k != "all":
                rows.append({**ceiling[0], "k": k})
    return pd.DataFrame(rows)


def acceptance(tab: pd.DataFrame, who: str = "personalised") -> list[str]:
    """The issue's acceptance lines on the pooled table, for the personalised agent `who` (a variant's column)."""
    lines = []
    pooled = tab[tab["group"] == "pooled"]
    for k, g in pooled.groupby("k", sort=False):
        g = g.set_index("policy")
        if who not in g.index:
            continue
        p = g.loc[who]
        rivals = g.loc[[r for r in RIVALS if r in g.index]]
        best = rivals["balanced_accuracy"].idxmax()
        ok = p["balanced_accuracy"] >= rivals.loc[best, "ba_lo"]
        lines.append(
            f"K={k}: {who} {100 * p['balanced_accuracy']:.1f} vs best other {best} "
            f"{100 * rivals.loc[best, 'balanced_accuracy']:.1f} [{100 * rivals.loc[best, 'ba_lo']:.1f}, "
            f"{100 * rivals.loc[best, 'ba_hi']:.1f}]: {'holds' if ok else 'FAILS'}"
        )
        if k == "10" and "ceiling" in g.index:
            gap = 100 * (g.loc["ceiling", "balanced_accuracy"] - p["balanced_accuracy"])
            lines.append(f"K=10: ceiling - {who} = {gap:+.1f} points (at most 3): {'holds' if gap <= 3 else 'FAILS'}")
    return lines


def print_table(tab: pd.DataFrame, title: str) -> None:
    print(f"\n{title}")
    print(f"{'K':>4}  {'policy':<34} {'n':>4}  {'balanced acc. [95 % CI]':<24} {'recall':>7}  timing MAE [s] [95 % CI]")
    for r in tab.itertuples():
        timing = (
            "-"
            if r.timing_mae_s is None or pd.isna(r.timing_mae_s)
            else f"{r.timing_mae_s:.2f} [{r.timing_lo:.2f}, {r.timing_hi:.2f}]"
        )
        print(
            f"{r.k:>4}  {r.policy:<34} {r.n_decisions:>4}  {100 * r.balanced_accuracy:5.1f} "
            f"[{100 * r.ba_lo:5.1f}, {100 * r.ba_hi:5.1f}]    {100 * r.recall:6.1f}  {timing}"
        )


def plot(tab: pd.DataFrame, path: Path, title: str) -> None:
    """Balanced accuracy against K, one line per policy, pooled (Plotly HTML)."""
    import plotly.graph_objects as go

    pooled = tab[tab["group"] == "pooled"]
    order = list(dict.fromkeys(pooled["k"]))
    fig = go.Figure()
    for who, g in pooled.groupby("policy", sort=False):
        g = g.set_index("k").reindex(order).dropna(subset=["balanced_accuracy"])
        fig.add_trace(
            go.Scatter(
                x=list(g.index),
                y=100 * g["balanced_accuracy"],
                mode="lines+markers",
                name=who,
                line={"dash": "dash"} if who == "ceiling" else None,
                error_y={
                    "type": "data",
                    "symmetric": False,
                    "array": 100 * (g["ba_hi"] - g["balanced_accuracy"]),
                    "arrayminus": 100 * (g["balanced_accuracy"] - g["ba_lo"]),
                },
            )
        )
    fig.update_layout(
        title=title,
        xaxis_title="decisions of the new driver (K)",
        yaxis_title="held-out balanced accuracy [%] (95 % CI)",
        template="plotly_white",
    )
    fig.write_html(path, include_plotlyjs=True)  # opens offline


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-w", "--workspace", required=True, type=Path, help="an analysed workspace")
    ap.add_argument("--drivers", default="all", help="'all', N (the first N) or ID,ID,... held out in turn")
    ap.add_argument("--k", default="5,10,20,all", help="decisions shown, comma-separated ('all': every earlier one)")
    ap.add_argument("--episodes", type=int, default=None, help="cap on every agent's episodes (default: the trainer's)")
    ap.add_argument(
        "--variants",
        default="none:blend",
        help="personalised agents, METHOD:BASE[:NAME=VALUE;...],... (the first is 'personalised'; "
        "default: laneprint personalize's, the blend of the candidates as it is; 'none:fit' the "
        "previous default)",
    )
    ap.add_argument(
        "--observation",
        default=None,
        choices=OBSERVATIONS,
        help="what every agent and classifier sees (default: the 'decisions' reward's own)",
    )
    ap.add_argument("--test-sessions", type=int, default=1, help="the driver's last sessions, held out")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--bootstrap", type=int, default=1000)
    ap.add_argument("--jobs", type=int, default=1, help="drivers in parallel processes")
    ap.add_argument("--out", type=Path, default=None, help="folder for curve.json/.csv/.html (default WS/benchmarks)")
    ap.add_argument("--result", default="personalize", help="result file name under benchmarks/results/")
    a = ap.parse_args()

    ws = Workspace(a.workspace)
    if not ws.has_table("analysis", "decisions"):
        sys.exit(f"no analysis in {a.workspace}: run `laneprint ingest ... && laneprint analyze -w {a.workspace}`")
    decisions = ws.read_table("analysis", "decisions")
    styles = ws.read_table("analysis", "styles")
    everyone = sorted(decisions["driver_id"].astype(str).unique())
    if a.drivers == "all":
        held = everyone
    elif a.drivers.isdigit():
        held = everyone[: int(a.drivers)]
    else:
        held = a.drivers.split(",")
    ks = tuple(ALL if k == "all" else int(k) for k in a.k.split(","))
    variants = parse_variants(a.variants)
    jobs = [
        (
            str(a.workspace),
            d,
            [o for o in everyone if o != d],
            a.episodes,
            a.seed,
            ks,
            variants,
            a.test_sessions,
            a.observation,
        )
        for d in held
    ]
    observation = resolve_formulation("decisions", None, a.observation)[2]
    print(
        f"personalise: {len(held)} held-out driver(s) of {len(everyone)}, K = {a.k}, episodes cap "
        f"{a.episodes or 'default'}, variants {a.variants}, observation {observation}, seed {a.seed}",
        flush=True,
    )
    t0 = time.perf_counter()
    results = []
    if a.jobs > 1:
        with ProcessPoolExecutor(a.jobs) as pool:
            for job, res in zip(jobs, pool.map(one_driver, jobs)):
                print(f"  {job[1]}: {res['n_test_decisions']} held-out decisions, {res['wall_s']:.0f} s", flush=True)
                results.append(res)
    else:
        for job in jobs:
            res = one_driver(job)
            print(f"  {job[1]}: {res['n_test_decisions']} held-out decisions, {res['wall_s']:.0f} s", flush=True)
            results.append(res)
    states = pd.concat([r["states"] for r in results], ignore_index=True)
    changes = pd.concat([r["changes"] for r in results], ignore_index=True)
    assigned = pd.concat([r["styles"] for r in results], ignore_index=True)
    true_style = dict(zip(styles["driver_id"].astype(str), styles["style"].astype(str)))
    assigned["true_style"] = assigned["driver"].map(true_style)
    policies = list(variants) + ["style", "population", "scratch", "imitation_k", "imitation_pop_k", "ceiling"]

    def tab_of(sel: pd.Series, group: str) -> pd.DataFrame:
        frame = pd.DataFrame()
        frame.attrs["states"] = states[sel(states)]
        frame.attrs["changes"] = changes[sel(changes)]
        return table(frame, policies, a.bootstrap, a.seed, group)

    tabs = [tab_of(lambda f: pd.Series(True, index=f.index), "pooled")]
    for style in sorted(set(true_style[d] for d in held)):
        members = {d for d in held if true_style[d] == style}
        tabs.append(tab_of(lambda f, m=members: f["driver"].isin(m), style))
    tab = pd.concat(tabs, ignore_index=True)
    order = {p: i for i, p in enumerate(policies)}
    korder = {k: i for i, k in enumerate(dict.fromkeys(states["k"]))}
    tab = tab.sort_values(
        ["group", "k", "policy"],
        key=lambda s: (
            s.map(order)
            if s.name == "policy"
            else s.map(korder)
            if s.name == "k"
            else s.map(lambda g: (g != "pooled", g))
        ),
        kind="stable",
    )
    for group, g in tab.groupby("group", sort=False):
        print_table(
            g,
            f"{group}: held out the last {a.test_sessions} session(s) of {len(held)} driver(s)"
            if group == "pooled"
            else f"style {group} (the full analysis's)",
        )
    print("\nstyle assigned from the K decisions (right / all, mean confidence):")
    for k, g in assigned.groupby("k", sort=False):
        print(f"  K={k}: {(g['style'] == g['true_style']).sum()} / {len(g)}, confidence {g['confidence'].mean():.2f}")
    print("\nacceptance (pooled; 'at least as good' = not below the best other policy's 95 % interval):")
    for line in acceptance(tab):
        print("  " + line)
    for who in list(variants)[1:]:  # the other variants, as if each were the headline
        print(f"  {who}:")
        for line in acceptance(tab, who):
            print("    " + line)
    out = a.out or a.workspace / "benchmarks"
    out.mkdir(parents=True, exist_ok=True)
    tab.to_csv(out / "curve.csv", index=False)
    states.to_pickle(out / "states.pkl")  # every policy's held-out states, per driver and K (for per-driver looks)
    changes.to_pickle(out / "changes.pkl")
    (out / "curve.json").write_text(
        json.dumps(
            {
                "args": {k: str(v) for k, v in vars(a).items()},
                "drivers": held,
                "observation": observation,
                "table": tab.replace({np.nan: None}).to_dict("records"),
                "styles": assigned.to_dict("records"),
                "acceptance": acceptance(tab),
                "acceptance_variants": {w: acceptance(tab, w) for w in list(variants)[1:]},
                "wall_s": time.perf_counter() - t0,
            },
            indent=2,
            default=str,
        )
    )
    write_result(
        a.result,
        {
            "drivers_held_out": len(held),
            "drivers": len(everyone),
            "k": a.k,
            "episodes": a.episodes or "the trainer's",
            "variants": a.variants,
            "observation": observation,
            "test_sessions": a.test_sessions,
            "seed": a.seed,
            "bootstrap": a.bootstrap,
            "wall_s": time.perf_counter() - t0,
            "acceptance": acceptance(tab),
            "acceptance_variants": {w: acceptance(tab, w) for w in list(variants)[1:]},
            "style_assigned": [
                {
                    "k": k,
                    "right": int((g["style"] == g["true_style"]).sum()),
                    "drivers": len(g),
                    "mean_confidence": float(g["confidence"].mean()),
                }
                for k, g in assigned.groupby("k", sort=False)
            ],
            "table": tab.replace({np.nan: None}).to_dict("records"),
        },
    )
    plot(tab, out / "curve.html", f"personalisation learning curve: {a.workspace.name}, {len(held)} drivers")
    print(f"\nwrote {out}/curve.csv, curve.json, curve.html ({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
