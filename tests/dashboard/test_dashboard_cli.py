import re
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from dashboard.cli import MAX_UPLOAD_MB, allowed_hosts, streamlit_command
from laneprint.app.cli import app

ROOT = Path(__file__).resolve().parents[2]


def test_streamlit_command_is_local_headless_and_private(tmp_path):
    cmd = streamlit_command(8999, "127.0.0.1", tmp_path)
    assert cmd[:4] == [sys.executable, "-m", "streamlit", "run"] and cmd[4].endswith("dashboard/app.py")
    args = cmd[5:]
    pairs = dict(zip(args[: args.index("--")][::2], args[: args.index("--")][1::2]))
    assert pairs["--server.address"] == "127.0.0.1" and pairs["--server.port"] == "8999"
    assert pairs["--server.headless"] == "true" and pairs["--browser.gatherUsageStats"] == "false"
    assert pairs["--server.maxUploadSize"] == str(MAX_UPLOAD_MB)
    assert args[args.index("--") + 1 :] == ["--workspace", str(tmp_path)]


def test_bad_port_is_one_line_exit_1(tmp_path):
    res = CliRunner().invoke(app, ["dashboard", "--port", "70000", "-w", str(tmp_path / "ws")])
    assert res.exit_code == 1
    assert "port 70000 is not a valid TCP port" in res.output and "Traceback" not in res.output


def test_only_the_dashboard_imports_streamlit():
    mine = {ROOT / "benchmarks" / "dashboard.py"}
    offenders = []
    paths = [
        p
        for top in ("laneprint", "ingest", "indicators", "clustering", "rl", "tests", "benchmarks")
        for p in (ROOT / top).rglob("*.py")
    ]
    assert len(paths) > 20
    for path in paths:
        rel = path.relative_to(ROOT)
        if rel.parts[:2] == ("tests", "dashboard") or path in mine:
            continue
        if re.search(r"^\s*(import|from)\s+streamlit\b", path.read_text(errors="ignore"), re.M):
            offenders.append(str(rel))
    assert offenders == []


def websocket_status(port: int, host_header: str) -> int:
    """The HTTP status of a WebSocket handshake to the dashboard under `host_header`."""
    import socket

    with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
        sock.sendall(
            (
                f"GET /_stcore/stream HTTP/1.1\r\nHost: {host_header}\r\nConnection: Upgrade\r\n"
                "Upgrade: websocket\r\nSec-WebSocket-Version: 13\r\n"
                "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n\r\n"
            ).encode()
        )
        return int(sock.recv(64).split()[1])


def test_allowed_hosts_are_this_machines():
    assert allowed_hosts("127.0.0.1") == ["localhost", "127.0.0.1", "::1"]
    assert "lab-pc" in allowed_hosts("lab-pc") and "*" not in allowed_hosts("0.0.0.0")


@pytest.mark.slow
def test_laneprint_dashboard_serves_and_stops(tmp_path):
    import os
    import signal
    import subprocess

    from dashboard_support import free_port, wait_healthy

    port = free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "laneprint.app.cli", "dashboard", "--port", str(port), "-w", str(tmp_path / "ws")],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    try:
        wait_healthy(f"http://127.0.0.1:{port}", proc)
        # DNS rebinding: a page whose name resolves here is another origin, refused at the WebSocket
        assert websocket_status(port, f"localhost:{port}") == 101
        assert websocket_status(port, f"rebind.example.com:{port}") == 403
        proc.send_signal(signal.SIGTERM)  # to the CLI only: it must stop the server it started
        out, _ = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert f"http://127.0.0.1:{port}" in out
    assert (tmp_path / "ws" / "recordings").is_dir()
    import socket

    with socket.socket() as s:  # nobody listens on the port any more: no server left behind
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # TIME_WAIT of the health checks is fine
        s.bind(("127.0.0.1", port))
