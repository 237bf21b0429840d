"""Where SUMO is, and one simulation at a time behind a small class.

The binaries come from the `eclipse-sumo` wheel (`sumo.SUMO_HOME/bin`, not on
PATH). A run goes in-process through `libsumo` when it is installed and through
`traci` (a socket to the `sumo` binary) otherwise; both expose the same API, so
`SumoSession` hands out the one that is there. Everything that talks to SUMO is
started and closed here.
"""

from __future__ import annotations

import contextlib
import io
import os
import socket
import subprocess
from pathlib import Path
from types import ModuleType
from typing import Any

from laneprint.errors import UserError

INSTALL_HINT = "Eclipse SUMO is not installed: pip install -e '.[sumo]'"


def sumo_home() -> Path:
    """SUMO_HOME of the `eclipse-sumo` wheel (raises `UserError` when it is missing)."""
    try:
        import sumo  # the eclipse-sumo wheel
    except ImportError:
        raise UserError(INSTALL_HINT) from None
    home = Path(sumo.SUMO_HOME)
    if not (home / "bin").is_dir():
        raise UserError(f"{INSTALL_HINT} ({home / 'bin'} not found)")
    return home


def binary(name: str) -> Path:
    """Path of a SUMO binary (`sumo`, `netconvert`)."""
    path = sumo_home() / "bin" / name
    if not path.is_file():
        raise UserError(f"{INSTALL_HINT} ({path} not found)")
    return path


def sumo_env() -> dict[str, str]:
    """Environment for SUMO's binaries (SUMO_HOME set, so they do not warn)."""
    return {**os.environ, "SUMO_HOME": str(sumo_home())}


def load_api() -> tuple[ModuleType, str]:
    """(module, name): `libsumo` when importable, else `traci`; `UserError` when neither is."""
    try:
        # libsumo prints a pyarrow version note on import; keep stdout clean for --json
        with contextlib.redirect_stdout(io.StringIO()):
            import libsumo
        return libsumo, "libsumo"
    except (ImportError, OSError):
        pass
    try:
        import traci
    except ImportError:
        raise UserError(INSTALL_HINT) from None
    return traci, "traci"


def check_available() -> str:
    """Raise `UserError` unless SUMO can run here; returns the API's name."""
    binary("netconvert")
    _, name = load_api()
    if name == "traci":
        binary("sumo")
    return name


def run_netconvert(nodes: Path, edges: Path, out: Path) -> Path:
    """Build `out` (a .net.xml) from plain node and edge files."""
    cmd = [
        str(binary("netconvert")),
        "-n",
        str(nodes),
        "-e",
        str(edges),
        "-o",
        str(out),
        "--no-turnarounds",
        "true",
        "--no-warnings",
        "true",
    ]
    res = subprocess.run(cmd, capture_output=True, text=True, env=sumo_env(), check=False)
    if res.returncode != 0:
        raise RuntimeError(f"netconvert failed: {res.stderr.strip() or res.stdout.strip()}")
    return out


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("localhost", 0))
        return int(sock.getsockname()[1])


class SumoSession:
    """One running simulation: `api.vehicle`, `api.simulation`, `step()`, `close()`.

    With libsumo there is one simulation per process (module-level state); with traci
    each session is its own connection to its own `sumo` process (not in traci's
    global pool), quiet on stdout so `--json` output stays clean.
    """

    def __init__(self, args: list[str]) -> None:
        self._module, self.api_name = load_api()
        if self.api_name == "libsumo":
            self._module.start(["sumo", *args])
            self.api: Any = self._module
        else:
            port = _free_port()
            proc = subprocess.Popen(
                [str(binary("sumo")), *args, "--remote-port", str(port)], stdout=subprocess.DEVNULL, env=sumo_env()
            )
            with contextlib.redirect_stdout(io.StringIO()):  # traci prints its connection retries
                self.api = self._module.connect(port, numRetries=200, proc=proc, waitBetweenRetries=0.05)
        self.version = str(self.api.getVersion()[1]).replace("SUMO ", "")

    def step(self) -> None:
        """Advance one step."""
        self.api.simulationStep()

    def close(self) -> None:
        """End the simulation (idempotent)."""
        if self.api is not None:
            with contextlib.suppress(Exception):
                self.api.close()
            self.api = None

    def __enter__(self) -> "SumoSession":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
