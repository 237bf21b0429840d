"""`laneprint dashboard`: serve the Streamlit app over a workspace."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
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


def allowed_hosts(host: str) -> list[str]:
    """The names a browser may reach the dashboard by: this machine's (and `host` when it is a name or
    address of its own). Any other Host header is refused, so a web page whose name resolves to
    127.0.0.1 (DNS rebinding) cannot drive the dashboard."""
    import socket

    names = ["localhost", "127.0.0.1", "::1"]
    if host in ("0.0.0.0", "::", ""):  # served to the network: the machine's own names too
        names += [socket.gethostname(), socket.getfqdn()]
    elif host not in names:
        names.append(host)
    return list(dict.fromkeys(n for n in names if n))


def streamlit_command(port: int, host: str, workspace: Path) -> list[str]:
    """The `streamlit run` command line serving the app (headless, no usage statistics, own hosts only)."""
    hosts = [arg for name in allowed_hosts(host) for arg in ("--server.allowedHosts", name)]
    return [
        sys.executable,
        "-m",
        "streamlit",
        "run",
        str(APP),
        *hosts,
        "--server.headless",
        "true",
        "--server.port",
        str(port),
        "--server.address",
        host,
        "--server.maxUploadSize",
        str(MAX_UPLOAD_MB),
        "--server.fileWatcherType",
        "none",
        "--browser.gatherUsageStats",
        "false",
        "--client.toolbarMode",
        "viewer",
        "--server.enableStaticServing",
        "true",  # the documentation site the help links open (docs_site.py)
        "--",
        "--workspace",
        str(workspace),
    ]


def _build_docs() -> None:
    """Build the documentation site the help links open when it is missing or stale (a checkout); one line on
    stderr when it cannot be built (the links are then left out)."""
    from dashboard.docs_site import ensure_site

    why = ensure_site()
    if why:
        err_console.print(f"note: no help links to the documentation: {why}", markup=False, highlight=False)


@configurable("dashboard")
def dashboard_command(
    workspace: WorkspaceOpt = DEFAULT_WS,
    port: Annotated[int, typer.Option("--port", "-p", help="TCP port to serve on.")] = 8501,
    host: Annotated[
        str, typer.Option("--host", help="Address to listen on (127.0.0.1: this machine only).")
    ] = "127.0.0.1",
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
    threading.Thread(target=_build_docs, daemon=True).start()  # the help links' pages, while the server starts
    env = dict(os.environ, LANEPRINT_WORKSPACE=str(ws.root))
    proc = subprocess.Popen(
        streamlit_command(port, host, ws.root), env=env, stdout=subprocess.DEVNULL if as_json else None
    )
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
