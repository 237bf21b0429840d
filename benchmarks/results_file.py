"""One result file of a benchmark: `benchmarks/results/<name>.json`, its figures with what produced them.

`write_result(name, figures)` adds the command (this benchmark's file name and arguments), the commit
(`git rev-parse HEAD` when this module was imported, i.e. when the benchmark started: a commit made while
it ran is not the code that ran; "" outside a checkout), the UTC date and the machine (node, architecture, cores)
to the figures, and writes them; `python -m laneprint.app.reference_docs` renders every such file on
the documentation's results page. Standard library only: any benchmark can import it first.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
#: Keys every result file has; a benchmark's figures cannot use them.
COMMON = ("command", "commit", "date", "machine")


def commit() -> str:
    """The checkout's HEAD, or "" where git or the repository is missing."""
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.SubprocessError):
        return ""
    return out.stdout.strip() if out.returncode == 0 else ""


def machine() -> str:
    """Node, architecture and cores, as the zoo's files have always said them: 'vm x86_64 2 cores'."""
    return f"{platform.node()} {platform.machine()} {os.cpu_count() or 0} cores"


#: The checkout's HEAD when the benchmark started (this module is imported first).
STARTED_AT = commit()


def _plain(value: Any) -> Any:
    """What json cannot write by itself: numpy scalars and arrays, paths, sets."""
    if hasattr(value, "tolist"):  # numpy scalar or array
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, (set, frozenset)):
        return sorted(value)
    return float(value)


def write_result(name: str, figures: dict, argv: list[str] | None = None) -> Path:
    """Write `benchmarks/results/<name>.json` (`name` may end in .json): the common keys, then `figures`.

    `argv`: the benchmark's arguments (default `sys.argv[1:]`); the command is the running script's file
    name followed by them.
    """
    clash = [k for k in COMMON if k in figures]
    if clash:
        raise ValueError(f"figures may not use the result file's own keys: {', '.join(clash)}")
    args = sys.argv[1:] if argv is None else list(argv)
    result = {
        "command": " ".join([Path(sys.argv[0]).name, *map(str, args)]),
        "commit": STARTED_AT,
        "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "machine": machine(),
        **figures,
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / (name if name.endswith(".json") else f"{name}.json")
    path.write_text(json.dumps(result, indent=1, default=_plain) + "\n", encoding="utf-8")
    print(f"wrote {path.relative_to(ROOT) if path.is_relative_to(ROOT) else path}", file=sys.stderr)
    return path
