"""Command-line entry of this stage (placeholder until the stage lands)."""

from laneprint.cliutil import DEFAULT_WS, JsonOpt, WorkspaceOpt
from laneprint.errors import UserError


def ingest_command(workspace: WorkspaceOpt = DEFAULT_WS, as_json: JsonOpt = False) -> None:
    """Not implemented yet."""
    raise UserError("this command is not implemented yet")
