"""`laneprint check [--repair]`: verify a workspace, and remove the leftovers of interrupted writes."""

from __future__ import annotations

from typing import Annotated, Any

import typer
from rich.console import Console

from laneprint.cliutil import DEFAULT_WS, JsonOpt, WorkspaceOpt, run_command
from laneprint.workspace import Workspace
from laneprint.options import configurable


def _render(res: dict[str, Any], console: Console) -> None:
    for f in res["findings"]:
        console.print(f"{f['kind']}: {f['path']}: {f['message']}", highlight=False, markup=False, soft_wrap=True)
    for line in res["repaired"]:
        console.print(f"repaired: {line}", highlight=False, markup=False, soft_wrap=True)
    c = res["counts"]
    verdict = "ok" if res["ok"] else "NOT OK"
    console.print(
        f"{verdict}: {res['n_recordings']} recordings, {res['n_runs']} runs checked; {c['problem']} "
        f"problem(s), {c['leftover']} leftover(s){' (run with --repair to remove them)' if c['leftover'] else ''}, "
        f"{len(res['repaired'])} repaired, {c['note']} note(s)",
        highlight=False,
        markup=False,
    )


@configurable("check")
def check_command(
    repair: Annotated[
        bool, typer.Option("--repair", help="Remove leftovers of interrupted writes (nothing else).")
    ] = False,
    workspace: WorkspaceOpt = DEFAULT_WS,
    as_json: JsonOpt = False,
) -> None:
    """Verify the workspace: recordings, tables, catalogue, runs, leftovers; exit 1 on a problem."""
    from laneprint.app.check import check_workspace

    run_command(lambda: check_workspace(Workspace(workspace), repair=repair), as_json, _render)
