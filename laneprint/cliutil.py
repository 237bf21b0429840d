"""What every command shares: the --workspace and --json options, one-line errors,
JSON output and a Rich progress bar.

A stage's command is a plain function returning a JSON-ready dict; `run_command`
turns its errors into one line on stderr with exit status 1 and prints either the
dict (--json) or the human summary drawn by `render`.
"""

from __future__ import annotations

import errno
import json
import re
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated, Any, Callable, Iterator, Mapping, Optional

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from laneprint.errors import SettingError, UserError
from laneprint.progress import ProgressFn
from laneprint.workspace import DEFAULT_WORKSPACE

WorkspaceOpt = Annotated[
    Path, typer.Option("--workspace", "-w", help="Workspace folder.", envvar="LANEPRINT_WORKSPACE")
]
JsonOpt = Annotated[bool, typer.Option("--json", help="Print one JSON document instead of the summary.")]
BackendOpt = Annotated[
    str,
    typer.Option(
        "--backend", help="Where the work runs: 'local' (this process) or 'ray' (Ray workers; pip install -e '.[ray]')."
    ),
]
RayAddressOpt = Annotated[
    Optional[str],
    typer.Option(
        "--ray-address",
        metavar="ADDR",
        hidden=True,
        help="With --backend ray: join this Ray cluster (host:port or 'auto'); default: start a local Ray instance "
        "with this machine's cores.",
    ),
]

#: C0 controls but tab and newline, DEL and C1: bytes that a terminal obeys as commands
_CONTROLS = re.compile(r"[\x00-\x08\x0b-\x1f\x7f-\x9f]")


def visible(value: Any) -> Any:
    """`value` (a str, or dicts and lists of them) with terminal control characters shown as escapes
    (\\x1b), so a file name or driver id from the data cannot clear the screen or retitle the window."""
    if isinstance(value, str):
        return _CONTROLS.sub(lambda m: f"\\x{ord(m.group()):02x}", value)
    if isinstance(value, dict):
        return {visible(k): visible(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(visible(v) for v in value)
    return value


#: what the machine, not the program, is to blame for: a folder that cannot be written, a full disk
_ENVIRONMENT_ERRNOS = {errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOSPC, errno.EDQUOT}

console = Console(stderr=False)
err_console = Console(stderr=True)

DEFAULT_WS = DEFAULT_WORKSPACE


def run_command(
    work: Callable[[], dict[str, Any]],
    as_json: bool,
    render: Callable[[dict[str, Any], Console], None],
    flags: Optional[Mapping[str, str]] = None,
) -> dict[str, Any]:
    """Run `work`; print its result as JSON or via `render`; exit 1 on a UserError (a `SettingError` says
    the command's flags for the settings it names: `flags[setting]`, else `--setting-name`)."""
    try:
        result = work()
    except UserError as exc:
        text = exc.as_flags(flags) if isinstance(exc, SettingError) else str(exc)
        err_console.print(f"error: {visible(text)}", markup=False, highlight=False, soft_wrap=True)
        raise typer.Exit(1) from None
    except OSError as exc:
        if exc.errno not in _ENVIRONMENT_ERRNOS:
            raise
        where = f": {exc.filename}" if exc.filename else ""
        err_console.print(
            f"error: {exc.strerror or exc}{visible(where)} (a read-only folder or a full disk?)",
            markup=False,
            highlight=False,
            soft_wrap=True,
        )
        raise typer.Exit(1) from None
    except KeyboardInterrupt:
        err_console.print("interrupted", markup=False)
        raise typer.Exit(130) from None
    if as_json:
        sys.stdout.write(json.dumps(result, indent=2, default=str) + "\n")
    else:
        render(visible(result), console)
    if result.get("exit_code"):
        raise typer.Exit(int(result["exit_code"]))
    return result


@contextmanager
def progress_bar(enabled: bool = True) -> Iterator[ProgressFn]:
    """A `ProgressFn` drawing a Rich bar on stderr (silent when disabled or not a terminal under --json)."""
    if not enabled:

        def silent(done: int, total: int, message: str = "") -> None:
            return None

        yield silent
        return
    bar = Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=err_console,
        transient=False,
    )
    task = bar.add_task("", total=None)
    with bar:
        last: dict[str, Any] = {"done": 0, "total": None}

        def update(done: int, total: int, message: str = "") -> None:
            if done < last["done"] or total != last["total"]:  # a new phase: its own bar and time estimate
                bar.reset(task, total=total, completed=done, description=visible(message)[:80])
            else:
                bar.update(task, completed=done, total=total, description=visible(message)[:80])
            last.update(done=done, total=total)

        yield update
