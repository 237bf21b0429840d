"""`laneprint dashboard`: serve the Streamlit app over a workspace."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Annotated

import typer

from laneprint.cliutil import DEFAULT_WS, JsonOpt, WorkspaceOpt, console, err_console
from laneprint.errors import UserError
from laneprint.workspace import Workspace
from laneprint.options import configurable

APP = Path(__file__).with_name("app.py")
#: Largest upload the server accepts [MB]; the Data page refuses bigger files with a hint.
MAX_UPLOAD_MB = 1024


def streamlit_command(port: int, host: str, workspace: Path) -> list[str]:
    """The `streamlit run` command line serving the app (headless, no usage statistics)."""
    return [sys.executable, "-m", "streamlit", "run", str(APP),
            "--server.headless", "true", "--server.port", str(port), "--server.address", host,
            "--server.maxUploadSize", str(MAX_UPLOAD_MB), "--server.fileWatcherType", "none",
            "--browser.gatherUsageStats", "false", "--client.toolbarMode", "viewer",
            "--", "--workspace", str(workspace)]


@configurable("dashboard")
def dashboard_command(
    workspace: WorkspaceOpt = DEFAULT_WS,
    port: Annotated[int, typer.Option("--port", "-p", help="TCP port to serve on.")] = 8501,
    host: Annotated[str, typer.Option("--host", help="Address to listen on (127.0.0.1: this machine only).")]
    = "127.0.0.1",
    as_json: JsonOpt = False,
) -> None:
    """Serve the dashboard until interrupted; prints the URL to open."""
    try:
        ws = Workspace(workspace).ensure()
        if not 0 < port < 65536:
            raise UserError(f"port {port} is not a valid TCP port (1-65535)")
    except UserError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(1) from None
    url = f"http://{'127.0.0.1' if host in ('0.0.0.0', '') else host}:{port}"
    if as_json:
        sys.stdout.write(json.dumps({"url": url, "workspace": str(ws.root)}) + "\n")
        sys.stdout.flush()
    else:
        console.print(f"laneprint dashboard on [bold]{url}[/bold] (workspace {ws.root}); Ctrl-C to stop")
    env = dict(os.environ, LANEPRINT_WORKSPACE=str(ws.root))
    proc = subprocess.Popen(streamlit_command(port, host, ws.root), env=env,
                            stdout=subprocess.DEVNULL if as_json else None)
    signal.signal(signal.SIGTERM, lambda *_: proc.terminate())  # stop the server with us
    try:
        code = proc.wait()
    except KeyboardInterrupt:
        proc.terminate()
        proc.wait()
        raise typer.Exit(0) from None
    if code:
        err_console.print(f"error: streamlit exited with status {code} (is port {port} free?)", markup=False)
        raise typer.Exit(1)
