"""The command-line and config-file reference pages of the documentation, generated from the app.

`python -m laneprint.app.reference_docs` writes `docs/reference/cli.md`, `docs/reference/config.md` and
`docs/reference/results.md` (every `benchmarks/results/*.json`: the zoo's layout as its tables, any other as
its figures listed and its lists of records as tables);
a test fails when the committed pages and the app differ, so the reference cannot drift.
"""

from __future__ import annotations

import sys
from pathlib import Path

import typer

from laneprint.app.cli import app
from laneprint.options import config_reference

PAGES = ("cli.md", "config.md", "results.md")
ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "benchmarks" / "results"


def _option_row(param: typer.core.click.Parameter) -> str:  # type: ignore[name-defined]
    flags = ", ".join(f"`{o}`" for o in [*param.opts, *param.secondary_opts])
    help_ = " ".join((getattr(param, "help", None) or "").split()).replace("|", "\\|")
    return f"| {flags} | {help_} |"


def cli_reference() -> str:
    """Markdown: every command, its arguments and its options shown in `--help`."""
    group = typer.main.get_command(app)
    out = ["# Command line", "",
           "Generated from the app (`python -m laneprint.app.reference_docs`). Each command shows its everyday "
           "options; every setting is also a key of a `--config FILE.toml` table "
           "([config reference](config.md)), and the research settings are there only.", ""]
    for name, cmd in group.commands.items():  # type: ignore[attr-defined]
        out += [f"## laneprint {name}", "", " ".join((cmd.help or "").split()), ""]
        args = [p for p in cmd.params if p.param_type_name == "argument"]
        if args:
            out += ["Arguments: " + ", ".join(f"`{a.name.upper()}`" for a in args), ""]
        opts = [p for p in cmd.params if p.param_type_name == "option" and not getattr(p, "hidden", False)
                and p.name != "help"]
        out += ["| option | what it does |", "|---|---|", *(_option_row(p) for p in opts), ""]
    return "\n".join(out)


def config_page() -> str:
    return ("# Config file\n\nEvery command takes `--config FILE.toml`. A table named after a command "
            "(`[train]`, `[drive]`) sets that command's options by their names (`episodes`, `learner`); the "
            "tables below set the settings of the stages, each key a field of a settings dataclass. A "
            "value resolves as: the default, then the file, then the command line. One file serves every "
            "command; each reads the tables it knows.\n\n```toml\n[analysis]\nfeatures = \"consensus\"\n\n"
            "[dqn]\nlearning_rate = 0.002\nnum_envs = 8\n\n[train]\nlearner = \"dqn\"\n```\n\n"
            + config_reference())


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
    out = ["Per world and method: mean and smallest adjusted Rand index over the seeds, share of drivers "
           "whose style name is right.", ""]
    out += _table(d["per_world"], [("world", "world", ""), ("method", "method", ""), ("seeds", "seeds", ""),
                                   ("mean_ari", "mean ARI", "f"), ("min_ari", "min ARI", "f"),
                                   ("names_right", "names right", "%")])
    out += ["Leave one world out: the method best on the other worlds, judged on this one.", ""]
    out += _table(d["leave_one_world_out"], [("world", "world", ""), ("method_chosen_elsewhere", "chosen", ""),
                                             ("mean_ari", "mean ARI", "f"), ("min_ari", "min ARI", "f")])
    out += ["Stated confidence against the share of drivers right, pooled over the worlds.", ""]
    out += _table(d["reliability"], [("method", "method", ""), ("confidence", "confidence", ""),
                                     ("drivers", "drivers", ""), ("share_right", "right", "%")])
    return out


def results_page() -> str:
    """Markdown: every result file of `benchmarks/results/`, with the command that reproduces it."""
    import json

    out = ["# Results", "", "Generated from `benchmarks/results/*.json` (`python -m laneprint.app.reference_docs`): "
           "each figure with the command, commit and date that produced it. Development seeds chose the "
           "methods; judged seeds were generated after.", ""]
    for path in sorted(RESULTS.glob("*.json")):
        d = json.loads(path.read_text(encoding="utf-8"))
        seeds = d.get("seeds")
        seeds = ", ".join(map(str, seeds)) if isinstance(seeds, list) else seeds
        out += [f"## {path.stem}", "", f"`python benchmarks/{d.get('command', '?')}`", "",
                f"commit `{str(d.get('commit') or '?')[:10]}`, {str(d.get('date', '?'))[:10]}, "
                f"{d.get('machine', '?')}" + (f"; seeds {seeds}" if seeds not in (None, "") else ""), ""]
        if {"per_world", "leave_one_world_out", "reliability"} <= d.keys():
            out += _zoo_section(d)
        else:
            out += _figures_section({k: v for k, v in d.items() if k not in RESULT_KEYS})
    return "\n".join(out)


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
            tables.extend([f"{name} ({len(v)} row{'s' * (len(v) != 1)}"
                           + (f", the first {MAX_ROWS} shown)" if len(v) > MAX_ROWS else ")"), "",
                           "| " + " | ".join(map(str, cols)) + " |", "|" + "---|" * len(cols),
                           *("| " + " | ".join(_cell(r.get(c, "")) for c in cols) + " |" for r in v[:MAX_ROWS]),
                           ""])
        else:
            bullets.append(f"- {name}: {_cell(v)}")
    walk("", figures)
    return bullets + [""] * bool(bullets) + tables


def pages() -> dict[str, str]:
    return {"cli.md": cli_reference() + "\n", "config.md": config_page() + "\n", "results.md": results_page() + "\n"}


def main(out: Path = ROOT / "docs" / "reference") -> None:
    out.mkdir(parents=True, exist_ok=True)
    for name, text in pages().items():
        (out / name).write_text(text, encoding="utf-8")
        print(f"wrote {out / name}", file=sys.stderr)


if __name__ == "__main__":
    main()
