"""The command-line, config-file and environment reference pages of the documentation, generated from the app.

`python -m laneprint.app.reference_docs` writes `docs/reference/cli.md`, `docs/reference/config.md`,
`docs/reference/environment.md` (every `LANEPRINT_*` variable: the workspace's, the ingest limits' from
`IngestLimits`, the dashboard's) and `docs/reference/results.md` (every `benchmarks/results/*.json`: the
zoo's layout as its tables, any other as its figures listed and its lists of records as tables);
a test fails when the committed pages and the app differ, so the reference cannot drift.
"""

from __future__ import annotations

import sys
from pathlib import Path

import typer

from laneprint.app.cli import app
from laneprint.options import config_reference

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "benchmarks" / "results"


def _option_row(param: typer.core.click.Parameter) -> str:  # type: ignore[name-defined]
    flags = ", ".join(f"`{o}`" for o in [*param.opts, *param.secondary_opts])
    help_ = " ".join((getattr(param, "help", None) or "").split()).replace("|", "\\|")
    return f"| {flags} | {help_} |"


def cli_reference() -> str:
    """Markdown: every command, its arguments and its options shown in `--help`."""
    group = typer.main.get_command(app)
    out = [
        "# Command line",
        "",
        "Generated from the app (`python -m laneprint.app.reference_docs`). Each command shows its everyday "
        "options; every setting is also a key of a `--config FILE.toml` table "
        "([config reference](config.md)), and the research settings are there only.",
        "",
    ]
    for name, cmd in group.commands.items():  # type: ignore[attr-defined]
        out += [f"## laneprint {name}", "", " ".join((cmd.help or "").split()), ""]
        args = [p for p in cmd.params if p.param_type_name == "argument"]
        if args:
            out += ["Arguments: " + ", ".join(f"`{a.name.upper()}`" for a in args), ""]
        opts = [
            p
            for p in cmd.params
            if p.param_type_name == "option" and not getattr(p, "hidden", False) and p.name != "help"
        ]
        out += ["| option | what it does |", "|---|---|", *(_option_row(p) for p in opts), ""]
    return "\n".join(out)


def config_page() -> str:
    return (
        "# Config file\n\nEvery command takes `--config FILE.toml`. A table named after a command "
        "(`[train]`, `[drive]`) sets that command's options by their names (`episodes`, `learner`); the "
        "tables below set the settings of the stages, each key a field of a settings dataclass. A "
        "value resolves as: the default, then the file, then the command line. One file serves every "
        'command; each reads the tables it knows.\n\n```toml\n[analysis]\nfeatures = "consensus"\n\n'
        '[dqn]\nlearning_rate = 0.002\nnum_envs = 8\n\n[train]\nlearner = "dqn"\n```\n\n'
        + config_reference()
        + "\n"
        + command_tables()
    )


def command_keys(cmd: typer.core.click.Command) -> list[tuple[str, typer.core.click.Parameter]]:  # type: ignore[name-defined]
    """(key, parameter) of each key a command's own `[command]` table takes: its options by their first long
    flag (`--run-id` -> `run_id`) and its arguments by name; the settings' options are their tables' keys."""
    out = []
    for p in cmd.params:
        if "__" in p.name or p.name in ("config", "help"):
            continue
        longs = [o for o in p.opts if o.startswith("--")]
        out.append((longs[0][2:].replace("-", "_") if p.param_type_name == "option" and longs else p.name, p))
    return out


def command_tables() -> str:
    """Markdown: each command's `[command]` table, every key (those `--help` shows and the ones it leaves out)."""
    group = typer.main.get_command(app)
    out = [
        "## Command tables",
        "",
        "A table named after a command sets that command's own options, by the names below (and, as "
        "`[train] episodes`, a setting the command shows in `--help`). Keys marked *not in --help* are "
        "research settings `--help` leaves out; the command line still takes them by their flag.",
        "",
    ]
    for name, cmd in group.commands.items():  # type: ignore[attr-defined]
        keys = command_keys(cmd)
        if not keys:
            continue
        out += [f"### [{name}]", "", "| key | flag | default | what it sets |", "|---|---|---|---|"]
        for key, p in keys:
            flag = (
                "argument"
                if p.param_type_name == "argument"
                else ", ".join(f"`{o}`" for o in [*p.opts, *p.secondary_opts])
            )
            default = p.default if p.default is not None and not callable(p.default) else None
            help_ = " ".join((getattr(p, "help", None) or "").split()).replace("|", "\\|")
            hidden = "*not in --help*: " if getattr(p, "hidden", False) else ""
            out.append(f"| `{key}` | {flag} | `{_default(default)}` | {hidden}{help_} |")
        out.append("")
    return "\n".join(out)


def _default(value: object) -> str:
    if value is None:
        return "none"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, (list, tuple)):
        return ", ".join(map(str, value)) or "none"
    return str(value)


def environment_variables() -> dict[str, str]:
    """Every `LANEPRINT_*` environment variable laneprint reads -> what it sets (Markdown)."""
    from dataclasses import fields

    from dashboard import context
    from ingest.limits import IngestLimits, env_var
    from laneprint.options import field_docs

    out = {
        context.WORKSPACE_ENV: "the workspace of every command when `--workspace` is not given "
        "(default `./workspace`); the dashboard's too"
    }
    docs, limits = field_docs(IngestLimits), IngestLimits()
    for f in fields(IngestLimits):
        help_ = " ".join(docs.get(f.name, "").replace(f"({env_var(f.name)})", "").split()).replace(" .", ".")
        out[env_var(f.name)] = (
            f"`laneprint ingest` (and the dashboard's uploads): {help_} Default `{getattr(limits, f.name):g}`."
        )
    for name, what in (
        (context.EPISODES_ENV, "episodes pre-filled in the Training form"),
        (context.POLL_ENV, "seconds between refreshes of the live views while a job runs"),
        (context.MAX_UPLOAD_ENV, "largest upload the Data and Personalize pages accept [MB]"),
    ):
        out[name] = f"the dashboard: {what} ([defaults](../dashboard.md#environment-variables))"
    return out


def environment_page() -> str:
    rows = ["| `" + name + "` | " + what.replace("|", "\\|") + " |" for name, what in environment_variables().items()]
    return "\n".join(
        [
            "# Environment variables",
            "",
            "Generated from the code (`python -m laneprint.app.reference_docs`): every `LANEPRINT_*` "
            "variable laneprint reads. A limit of `laneprint ingest` that is not a positive number "
            "stops the command with a one-line message; a log beyond a limit is refused with its "
            "reason and the variable that raises it.",
            "",
            "| variable | what it sets |",
            "|---|---|",
            *rows,
            "",
        ]
    )


def _table(rows: list[dict], cols: list[tuple[str, str, str]]) -> list[str]:
    """Markdown rows of `rows` (dicts): columns (key, header, format: '' plain, '%' percent, 'f' 2 decimals)."""

    def cell(v: object, fmt: str) -> str:
        if isinstance(v, (int, float)) and not isinstance(v, bool) and fmt:
            return f"{100 * v:.0f} %" if fmt == "%" else f"{v:.2f}"
        return str(v)

    out = ["| " + " | ".join(h for _, h, _ in cols) + " |", "|" + "---|" * len(cols)]
    out += ["| " + " | ".join(cell(r.get(k), f) for k, _, f in cols) + " |" for r in rows]
    return out + [""]


def _zoo_section(d: dict) -> list[str]:
    out = [
        "Per world and method: mean and smallest adjusted Rand index over the seeds, share of drivers "
        "whose style name is right.",
        "",
    ]
    out += _table(
        d["per_world"],
        [
            ("world", "world", ""),
            ("method", "method", ""),
            ("seeds", "seeds", ""),
            ("mean_ari", "mean ARI", "f"),
            ("min_ari", "min ARI", "f"),
            ("names_right", "names right", "%"),
        ],
    )
    out += ["Leave one world out: the method best on the other worlds, judged on this one.", ""]
    out += _table(
        d["leave_one_world_out"],
        [
            ("world", "world", ""),
            ("method_chosen_elsewhere", "chosen", ""),
            ("mean_ari", "mean ARI", "f"),
            ("min_ari", "min ARI", "f"),
        ],
    )
    out += ["Stated confidence against the share of drivers right, pooled over the worlds.", ""]
    out += _table(
        d["reliability"],
        [
            ("method", "method", ""),
            ("confidence", "confidence", ""),
            ("drivers", "drivers", ""),
            ("share_right", "right", "%"),
        ],
    )
    return out


#: The results pages: (file, title, what it shows, the result files' names or name prefixes it holds).
#: A result file no topic claims is shown on the results index itself.
RESULT_TOPICS: tuple[tuple[str, str, str, tuple[str, ...]], ...] = (
    (
        "results-styles.md",
        "Results: styles",
        "How well `laneprint analyze` reads the drivers' styles: per world and method (the zoo of worlds, "
        "one world held out), the consensus, SUMO studies and the analysis stage's own checks.",
        ("analysis", "consensus", "sumo_styles"),
    ),
    (
        "results-agents.md",
        "Results: agents",
        "How well the agents decide like their drivers: per learner, held out by session, personalised "
        "from a few decisions, against the classifiers' ceiling, in closed loop.",
        ("learners", "generalization", "personalize", "ceiling", "function_class", "train", "sides", "closed_loop"),
    ),
    (
        "results-speed.md",
        "Results: speed",
        "How long the stages take: a fleet against one agent at a time, the local backend against Ray, "
        "the analysis, the simulator, the test lanes.",
        ("fleet", "parallel", "analyze_speed", "simulate", "lanes"),
    ),
    (
        "results-ingest.md",
        "Results: ingest and robustness",
        "Ingest speed against the floor of reading the bytes, per format and stack; mutated logs (fuzz) and "
        "commands killed at random moments (crash).",
        ("ingest", "fuzz", "crash"),
    ),
    (
        "results-dashboard.md",
        "Results: dashboard",
        "Time to a drawn page of each dashboard page: the script run cold and warm, and in a browser.",
        ("dashboard",),
    ),
)
#: Every page `main` writes under docs/reference/.
PAGES = ("cli.md", "config.md", "environment.md", "results.md", *(t[0] for t in RESULT_TOPICS))
HEAD = (
    "Generated from `benchmarks/results/*.json` (`python -m laneprint.app.reference_docs`): each figure "
    "with the command that reproduces it (run from the repository's root), and the commit, date and "
    "machine that produced it. Development seeds chose the methods; judged seeds were generated after."
)


def topic_of(stem: str) -> str | None:
    """The results page a result file (by its name) belongs on; None: the index."""
    for page, _, _, names in RESULT_TOPICS:
        if any(stem == n or stem.startswith(n + "_") for n in names):
            return page
    return None


def _result_section(path: Path) -> list[str]:
    import json

    d = json.loads(path.read_text(encoding="utf-8"))
    seeds = d.get("seeds")
    seeds = ", ".join(map(str, seeds)) if isinstance(seeds, list) else seeds
    out = [
        f"## {path.stem}",
        "",
        f"`python benchmarks/{d.get('command', '?')}`",
        "",
        f"commit `{str(d.get('commit') or '?')[:10]}`, {str(d.get('date', '?'))[:10]}, "
        f"{d.get('machine', '?')}" + (f"; seeds {seeds}" if seeds not in (None, "") else ""),
        "",
    ]
    if {"per_world", "leave_one_world_out", "reliability"} <= d.keys():
        return out + _zoo_section(d)
    return out + _figures_section({k: v for k, v in d.items() if k not in RESULT_KEYS})


def results_pages() -> dict[str, str]:
    """Markdown pages: the index (`results.md`: the pages, and any result file no topic claims) and one
    page per topic of `RESULT_TOPICS`, every result file with the command that reproduces it."""
    files = sorted(RESULTS.glob("*.json"))
    pages: dict[str, list[str]] = {
        page: [f"# {title}", "", what, "", HEAD, ""] for page, title, what, _ in RESULT_TOPICS
    }
    index = ["# Results", "", HEAD, "", "| page | result files |", "|---|---|"]
    for page, title, _, _ in RESULT_TOPICS:
        held = [f.stem for f in files if topic_of(f.stem) == page]
        index.append(f"| [{title.removeprefix('Results: ')}]({page}) | {', '.join(held) or '-'} |")
    index.append("")
    for path in files:
        topic = topic_of(path.stem)
        (pages[topic] if topic else index).extend(_result_section(path))
    for page, _, _, names in RESULT_TOPICS:
        if len(pages[page]) == 6:
            pages[page] += [
                "No result file yet; these benchmarks write one: "
                + ", ".join(f"`python benchmarks/{n}.py`" for n in names if (ROOT / "benchmarks" / f"{n}.py").exists())
                + ".",
                "",
            ]
    return {"results.md": "\n".join(index), **{page: "\n".join(lines) for page, lines in pages.items()}}


def results_page() -> str:
    """Every result file of `benchmarks/results/`, the index and the topic pages one after the other."""
    return "\n".join(results_pages().values())


#: What every result file says besides its figures (`benchmarks/results_file.py`), shown in each section's head.
RESULT_KEYS = ("command", "commit", "date", "machine", "seeds")
#: Rows of a list of records shown on the page (the file holds all of them).
MAX_ROWS = 40


def _cell(v: object) -> str:
    """One figure as text: floats to 4 significant digits, lists and tables as short JSON."""
    import json

    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, (dict, list)):
        v = json.dumps(v, separators=(", ", ": "), default=str)
    text = " ".join(str(v).split()).replace("|", "\\|")
    return text if len(text) <= 120 else text[:117] + "..."


def _figures_section(figures: dict) -> list[str]:
    """Any other layout: scalars (nested tables by dotted name) as a list, lists of records as tables."""
    bullets: list[str] = []
    tables: list[str] = []

    def walk(name: str, v: object) -> None:
        if isinstance(v, dict) and v:
            for k, sub in v.items():
                walk(f"{name}.{k}" if name else str(k), sub)
        elif isinstance(v, list) and v and all(isinstance(r, dict) for r in v):
            cols = list(dict.fromkeys(k for r in v for k in r))
            tables.extend(
                [
                    f"{name} ({len(v)} row{'s' * (len(v) != 1)}"
                    + (f", the first {MAX_ROWS} shown)" if len(v) > MAX_ROWS else ")"),
                    "",
                    "| " + " | ".join(map(str, cols)) + " |",
                    "|" + "---|" * len(cols),
                    *("| " + " | ".join(_cell(r.get(c, "")) for c in cols) + " |" for r in v[:MAX_ROWS]),
                    "",
                ]
            )
        else:
            bullets.append(f"- {name}: {_cell(v)}")

    walk("", figures)
    return bullets + [""] * bool(bullets) + tables


def pages() -> dict[str, str]:
    return {
        "cli.md": cli_reference() + "\n",
        "config.md": config_page() + "\n",
        "environment.md": environment_page() + "\n",
        **{name: text + "\n" for name, text in results_pages().items()},
    }


def main(out: Path = ROOT / "docs" / "reference") -> None:
    out.mkdir(parents=True, exist_ok=True)
    for name, text in pages().items():
        (out / name).write_text(text, encoding="utf-8")
        print(f"wrote {out / name}", file=sys.stderr)


if __name__ == "__main__":
    main()
