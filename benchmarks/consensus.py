"""How many readings vote, and how the drivers are cut: `--features consensus` chosen one world out.

On the zoo of worlds (`benchmarks/zoo.py`, studies cached under `--root`), every study's
readings are ranked once as `--features separated` ranks them (`clustering.choice.ranked_readings`);
then each variant of the consensus (the N best readings vote, cut by average or complete
linkage; N = 1 is `separated` itself) reads the drivers, and its ARI against the study's truth is
recorded; '<variant>/no-v_free' is the same without the readings of the free speed, '/no-lc_rate' without
those of the lane-change rate; '-disjoint' variants let only voters that share no parameter with a better
one vote, '-shared' ones let every parameter speak once (`shared_weights`); '+read' and '+nosingle' ones
leave out the votes a reading has not earned (`PRUNED`). A variant is
chosen only if it reads the study shipped in `sample_logs/` right (ARI 1 and every name right: the acceptance
asks it). Each variant's groups are named as the library names them, and the share of drivers named right is
recorded beside the ARI. The leave-one-world-out table gives, for each world, the variant with the best mean ARI
on the *other* worlds and its ARI on this one. Written to `benchmarks/results/<--out>` with the
command, commit, date and machine.

Run: .venv/bin/python benchmarks/consensus.py [--worlds highway-2,...] [--seeds 9001 9101 ...] [--shares 'world;2,4,3']
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import Counter
from pathlib import Path

import pandas as pd
from sklearn.metrics import adjusted_rand_score

sys.path.insert(0, str(Path(__file__).resolve().parent))
import zoo  # noqa: E402
from results_file import write_result  # noqa: E402

#: variant name -> (voters, linkage); one voter is `separated`
#: variant name -> (voters, linkage, vote floor: share of the best reading's score a voter needs)
VARIANTS: dict[str, tuple[int, str, float]] = (
    {"separated": (1, "complete", 0.0)}
    | {f"top{n}-{link}": (n, link, 0.0) for n in (3, 5, 8, 99) for link in ("average", "complete")}
    | {f"top{n}-complete-floor{f}": (n, "complete", f) for n in (5, 8) for f in (0.3, 0.5)}
)
#: Variants whose voters share no parameter: a reading that reads a parameter a better one already reads
#: does not vote (the headway at the press, the headway while following and the reading of both are not
#: three opinions).
DISJOINT: dict[str, tuple[int, str, float]] = {
    f"top{n}-{link}-disjoint": (n, link, 0.0) for n in (3, 5) for link in ("average", "complete")
}
#: Variants whose voters share their parameters' say: each voter's weight times the mean over its parameters
#: of 1 / (the number of voters reading that parameter), so a parameter read by three voters speaks once.
SHARED: dict[str, tuple[int, str, float]] = {
    f"top{n}-{link}-shared": (n, link, 0.0) for n in (3, 5, 8) for link in ("average", "complete")
}
#: Variants that give no reading a say it has not earned: '+read' leaves out a reading's vote on the drivers it
#: could not estimate (a parameter missing, imputed as the median), '+nosingle' lets no reading vote whose smallest
#: style holds one driver (`clustering.consensus`); the library's default is one of these.
PRUNED: dict[str, tuple[int, str, float]] = {
    f"top{n}-{link}{flags}": (n, link, 0.0)
    for n in (3, 4, 5)
    for link in ("average", "complete")
    for flags in ("+read", "+nosingle", "+read+nosingle")
} | {f"top4-{link}": (4, link, 0.0) for link in ("average", "complete")}
#: The pruned votes with each parameter speaking once ('-shared', '-disjoint' after '+read+nosingle').
PRUNED_ONCE: dict[str, tuple[int, str, float]] = {
    f"top{n}-average+read+nosingle{once}": (n, "average", 0.0) for n in (3, 4, 5) for once in ("-shared", "-disjoint")
}
#: The pruned votes with each reading's say weighed by the other parameters' agreement with it and the voters
#: those with the most say ('+agree-mean', '+agree-top3': `clustering.consensus.agreement`); '+plainnames' names
#: the groups by the voters' silhouette x stability instead of their say (the agreement is an ARI: blind to names).
AGREED: dict[str, tuple[int, str, float]] = {
    f"top{n}-average+read+nosingle+agree-{how}{names}": (n, "average", 0.0)
    for n in (3, 4, 5, 6)
    for how in ("mean", "top3")
    for names in ("", "+plainnames")
}
ALL_VARIANTS = VARIANTS | DISJOINT | SHARED | PRUNED | PRUNED_ONCE | AGREED


#: The study shipped in `sample_logs/`: a variant must read it right (ARI 1) to be chosen.
SHIPPED = Path(__file__).resolve().parent.parent / "sample_logs"


def ranked(world: str, seed: int, root: Path, shares: str = "") -> tuple[dict[str, str], list]:
    """(truth, readings best first) of one cached study (style `shares` "2,4,3"; "" the world's own)."""
    out, ws = zoo.study(world, seed, root, shares)
    return ranked_study(out, ws)


def shipped(root: Path) -> tuple[dict[str, str], list]:
    """(truth, readings best first) of the shipped study, ingested under `root` once."""
    ws = root / "shipped.ws"
    if not (ws / "zoo_decisions.parquet").exists():
        zoo.laneprint("ingest", str(SHIPPED), "-w", str(ws), "--json")
    return ranked_study(SHIPPED, ws)


def ranked_study(out: Path, ws: Path) -> tuple[dict[str, str], list]:
    """(truth, readings best first) of the study generated in `out` and ingested in `ws`."""
    from clustering import choice as C
    from clustering.behaviour import driver_behaviour
    from clustering.pipeline import _n_decisions, indicator_points
    from indicators.settings import AnalysisSettings

    truth = {d["driver_id"]: d["style"] for d in json.loads((out / "ground_truth.json").read_text())["drivers"]}
    dec, following, drivers = zoo.decisions_of(ws)
    settings = AnalysisSettings(features="consensus")
    drivers = sorted(set(map(str, dec["driver_id"].unique())) | set(drivers))
    points = indicator_points(dec, settings, following)
    n_dec = _n_decisions(dec, drivers)
    behaviour = driver_behaviour(dec, following, drivers, settings.random_state)
    fit_on = [d for d in drivers if n_dec.get(d, 0) >= settings.min_cluster_decisions]
    scores, _ = C.ranked_readings(points, drivers, fit_on, n_dec, behaviour, settings)
    return truth, scores


#: Behaviour parameters a variant can do without: '<variant>/no-<param>' drops every reading of it.
WITHOUT: tuple[str, ...] = ("v_free", "lc_rate")


def without(scores: list, param: str) -> list:
    """The readings that do not read `param`."""
    return [r for r in scores if param not in r.parameters]


def variant_aris(truth: dict[str, str], scores: list) -> dict[str, tuple[float, float]]:
    """Every variant's (ARI, share of drivers named right) on one study, and each one's without every parameter
    of `WITHOUT`."""
    out = {}
    for name, (n, link, floor) in ALL_VARIANTS.items():
        flags = {
            "read": "+read" in name,
            "nosingle": "+nosingle" in name,
            "shared": "-shared" in name,
            "disjoint_voters": "-disjoint" in name,
            "agree": name.split("+agree-")[1].removesuffix("+plainnames") if "+agree-" in name else "",
            "plain_names": name.endswith("+plainnames"),
        }
        out[name] = variant_ari(truth, scores, n, link, floor, **flags)
        for param in WITHOUT:
            out[f"{name}/no-{param}"] = variant_ari(truth, without(scores, param), n, link, floor, **flags)
    return out


def disjoint(scores: list) -> list:
    """The readings, best first, that share no parameter with a better reading kept before them."""
    kept: list = []
    used: set[str] = set()
    for r in scores:
        params = set(r.parameters)
        if params & used:
            continue
        kept.append(r)
        used |= params
    return kept


def shared_weights(voting: list) -> list[float]:
    """Each voter's weight times the mean over its parameters of 1 / (voters reading that parameter)."""
    from clustering.consensus import weight

    readers = Counter(p for r in voting for p in r.parameters)
    return [weight(r) * float(sum(1 / readers[p] for p in r.parameters) / len(r.parameters)) for r in voting]


def variant_ari(
    truth: dict[str, str],
    scores: list,
    voters: int,
    method: str,
    floor: float = 0.0,
    k: int = 3,
    shared: bool = False,
    read: bool = False,
    nosingle: bool = False,
    disjoint_voters: bool = False,
    agree: str = "",
    plain_names: bool = False,
) -> tuple[float, float]:
    """(ARI, share of drivers named right) of one variant on one study: the `voters` best readings (those with a
    one-driver style left out with `nosingle`, then those sharing a parameter with a better one with
    `disjoint_voters`) vote, each on every driver it labels (with `read`, not on those it could not estimate),
    and name the groups as the library does (`vote_defensiveness`). With `agree` ('mean', 'top3'), the
    library's `votes` choose the voters and their say (`nosingle` and `read` implied), and the groups are named
    by that say unless `plain_names`."""
    from clustering.consensus import consensus_groups, votes, weight, without_outlier_splits

    if not scores:
        return float("nan"), float("nan")
    drivers = sorted(scores[0].labels)
    if agree:
        voting, say = votes(scores, n=voters, how=agree)
        groups = consensus_groups(voting, drivers, k, method, say, skip_unread=True)
        return scored(truth, drivers, groups, voting, None if plain_names else say)
    if nosingle:
        scores = without_outlier_splits(scores)
    if disjoint_voters:
        scores = disjoint(scores)
    voting = [r for r in scores[:voters] if weight(r) >= floor * weight(scores[0])]
    if len(voting) == 1:
        keep = [d for d in drivers if d in truth]
        ari = float(adjusted_rand_score([truth[d] for d in keep], [voting[0].labels[d] for d in keep]))
        return ari, float(sum(voting[0].labels[d] == truth[d] for d in keep) / max(len(keep), 1))
    weights = shared_weights(voting) if shared else None
    groups = consensus_groups(voting, drivers, k, method, weights, skip_unread=read)
    return scored(truth, drivers, groups, voting, weights)


def scored(truth: dict[str, str], drivers: list[str], groups, voting: list, weights: list[float] | None):
    """(ARI, share of drivers named right) of `groups`, named as `voting` (weighed by `weights`, or by each
    reading's silhouette x stability) name their members, as `clustering.choice.choose_consensus` does."""
    import numpy as np

    from clustering.consensus import vote_defensiveness
    from clustering.styles import style_names

    groups = np.asarray(groups)
    keep = [i for i, d in enumerate(drivers) if d in truth]
    ari = float(adjusted_rand_score([truth[drivers[i]] for i in keep], [groups[i] for i in keep]))
    defensive = vote_defensiveness(voting, drivers, groups, weights)
    ids = sorted(set(groups.tolist()))
    ranked = sorted(ids, key=lambda g: -defensive[g])  # most defensive first; ties keep the ids' order
    names = dict(zip(ranked, style_names(len(ids))))
    right = sum(names[groups[i]] == truth[drivers[i]] for i in keep)
    return ari, float(right / max(len(keep), 1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--worlds", default="all", help="worlds of benchmarks/zoo.py, comma-separated ('all': every one)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[9001, *range(9101, 9109)])
    ap.add_argument("--root", type=Path, default=Path("/tmp/laneprint-zoo"), help="where studies are cached")
    ap.add_argument("--out", default="analysis_consensus_dev.json", help="file name under benchmarks/results/")
    ap.add_argument("--cached-only", action="store_true", help="only the studies already generated under --root")
    ap.add_argument(
        "--shares",
        default="world",
        help="style groups of the studies, ';'-separated: 'world' (each world's own) and/or D,N,A e.g. '2,4,3'",
    )
    args = ap.parse_args()
    worlds = list(zoo.WORLDS) if args.worlds == "all" else args.worlds.split(",")
    truth, scores = shipped(args.root)
    on_shipped = variant_aris(truth, scores)  # variant -> (ARI, share named right)
    shares_list = ["" if s == "world" else s for s in args.shares.split(";")]
    rows = []
    for world in worlds:
        for seed in args.seeds:
            for shares in shares_list:
                if args.cached_only and not zoo.cached(world, seed, args.root, shares):
                    continue
                t0 = time.perf_counter()
                try:
                    truth, scores = ranked(world, seed, args.root, shares)
                except Exception as exc:  # a study that cannot be generated is reported, the rest go on
                    print(f"  {world} seed {seed}: {exc}", flush=True)
                    continue
                rows += [
                    {
                        "world": world,
                        "seed": seed,
                        "shares": shares or "world",
                        "variant": v,
                        "ari": a,
                        "names_right": nr,
                    }
                    for v, (a, nr) in variant_aris(truth, scores).items()
                ]
                print(f"  {world:<18} seed {seed:5d} {shares}  ({time.perf_counter() - t0:.0f} s)", flush=True)
    df = pd.DataFrame(rows)
    per = (
        df.groupby(["variant", "world"])
        .agg(
            mean_ari=("ari", "mean"),
            min_ari=("ari", "min"),
            names_right=("names_right", "mean"),
            seeds=("ari", "count"),
        )
        .reset_index()
    )
    means = per.pivot(index="variant", columns="world", values="mean_ari")
    names = per.pivot(index="variant", columns="world", values="names_right")
    eligible = means[[min(on_shipped.get(str(v), (0.0, 0.0))) >= 1.0 - 1e-9 for v in means.index]]
    lowo = []
    for world in means.columns if len(means.columns) > 1 else []:  # one world leaves none to choose on
        pick = str(eligible.drop(columns=world).mean(axis=1).idxmax())
        lowo.append(
            {
                "world": world,
                "variant_chosen_elsewhere": pick,
                "mean_ari": float(means.loc[pick, world]),
                "names_right": float(names.loc[pick, world]),
                "separated_mean_ari": float(means.loc["separated", world]),
            }
        )
    overall = pd.DataFrame(
        {
            "mean_over_worlds": means.mean(axis=1),
            "worst_world": means.min(axis=1),
            "names_right_over_worlds": names.mean(axis=1),
            "shipped_ari": pd.Series({v: a for v, (a, _) in on_shipped.items()}),
            "shipped_names_right": pd.Series({v: nr for v, (_, nr) in on_shipped.items()}),
        }
    )
    write_result(
        args.out,
        {
            "worlds": worlds,
            "seeds": args.seeds,
            "shares": args.shares,
            "per_study": df.pivot_table(index=["world", "seed", "shares"], columns="variant", values="ari")
            .reset_index()
            .to_dict("records"),
            "per_study_names_right": df.pivot_table(
                index=["world", "seed", "shares"], columns="variant", values="names_right"
            )
            .reset_index()
            .to_dict("records"),
            "variants": {k: list(v) for k, v in ALL_VARIANTS.items()},
            "per_world": per.to_dict("records"),
            "overall": overall.reset_index().to_dict("records"),
            "leave_one_world_out": lowo,
        },
    )
    print("\nmean ARI over worlds (worst world; names right; the shipped study's ARI) per variant")
    for v, r in overall.sort_values("mean_over_worlds", ascending=False).iterrows():
        print(
            f"  {v:<18} {r.mean_over_worlds:.3f} ({r.worst_world:.2f}; {r.names_right_over_worlds:.1%}; {r.shipped_ari:.2f})"
        )
    print(
        "\nleave one world out: the variant best on the other worlds among those that read the shipped study right "
        "(groups and names), judged on this one"
    )
    for r in lowo:
        print(
            f"  {r['world']:<18} {r['variant_chosen_elsewhere']:<16} {r['mean_ari']:.2f}, names {r['names_right']:.1%} "
            f"(separated {r['separated_mean_ari']:.2f})"
        )


if __name__ == "__main__":
    main()
