"""`laneprint check`: is a workspace whole? Every stored file read back and compared
with what the rest of the workspace says about it.

A finding is one of:

- ``problem``: something is wrong (an unreadable or missing file, a table that does
  not fit its schema, a catalogue that disagrees with the folders, a run whose files
  contradict each other); only a person can decide what to do;
- ``leftover``: what an interrupted write left behind (a temporary file or folder no
  live process holds, a session claim or a rejection record made stale by a kill, an
  empty run folder); `--repair` removes exactly these;
- ``note``: worth knowing, not wrong (an interrupted training run to resume, a live
  writer's temporary file, a source log that changed since it was ingested).

Whether a temporary file is a leftover is decided by its lock (`laneprint.locks`):
writers hold it until their file is in place, and the kernel drops it when they die.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

import pandas as pd
import pyarrow.parquet as pq

from laneprint.errors import UserError
from laneprint.locks import is_locked
from laneprint.schemas import (
    DECISIONS,
    EGO,
    RECORDINGS,
    REFERENCE_LINES,
    REJECTED,
    TRAFFIC,
    Schema,
    SchemaError,
    validate,
)
from laneprint.workspace import TMP_SUFFIX, Workspace, content_id, legacy_content_id

#: tables of a stage folder that have a schema (the others are checked for being readable)
STAGE_SCHEMAS: dict[tuple[str, str], Schema] = {
    ("analysis", "decisions"): DECISIONS,
    ("analysis", "reference_lines"): REFERENCE_LINES,
}
RECORDING_FILES: dict[str, Schema] = {"meta.parquet": RECORDINGS, "ego.parquet": EGO, "traffic.parquet": TRAFFIC}
# a temporary file or folder exists a moment before its writer locks it: one younger than this
# and unlocked is looked at again once it is this old
_CREATION_GRACE_S = 0.5


@dataclass
class Finding:
    """One line of the report."""

    kind: str  # 'problem' | 'leftover' | 'note'
    path: str  # relative to the workspace root
    message: str

    def line(self) -> str:
        return f"{self.kind}: {self.path}: {self.message}"


@dataclass
class _Leftover:
    finding: Finding
    remove: Callable[[], None]  # raises OSError when it cannot
    verb: str = "removed"


QUARANTINE = "quarantine"  # damaged recordings and tables are moved here by --repair, not deleted


def _quarantiner(ws: Workspace, path: Path) -> Callable[[], None]:
    """Move `path` (a recording folder, a table) to `quarantine/` under its relative path, beside any
    earlier one of the same name, so the rest of the workspace reads again."""

    def move() -> None:
        target = ws.root / QUARANTINE / _rel(ws, path)
        k = 1
        while target.exists():
            target = target.with_name(f"{target.name.split('~')[0]}~{k}")
            k += 1
        target.parent.mkdir(parents=True, exist_ok=True)
        os.rename(path, target)

    return move


def _rel(ws: Workspace, path: Path) -> str:
    try:
        return str(path.relative_to(ws.root)) or "."
    except ValueError:
        return str(path)


def _unheld(path: Path) -> bool:
    """True when no live process holds `path` (one just created is given its moment to lock it)."""
    if is_locked(path):
        return False
    try:
        age = time.time() - path.lstat().st_mtime
    except OSError:
        return False
    if age < _CREATION_GRACE_S:
        time.sleep(_CREATION_GRACE_S - age)
        return path.exists() and not is_locked(path)
    return True


def _remover(path: Path) -> Callable[[], None]:
    def remove() -> None:
        if path.is_dir() and not path.is_symlink():
            errors: list[BaseException] = []
            shutil.rmtree(path, onerror=lambda fn, p, info: errors.append(info[1]))
            if errors or path.exists():
                raise errors[0] if errors else OSError(f"{path} is still there")
        else:
            path.unlink(missing_ok=True)

    return remove


def _read_json(path: Path) -> Any:
    return json.loads(path.read_text(encoding="utf-8"))


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}"


# --- leftovers of interrupted writes -------------------------------------------------------


def _temp_leftovers(ws: Workspace) -> Iterator[_Leftover | Finding]:
    """Staging folders under `.tmp/` and `.<name>.<random>.tmp` files anywhere."""
    tmp_root = ws.root / ".tmp"
    for p in sorted(tmp_root.iterdir()) if tmp_root.is_dir() else []:
        if _unheld(p):
            yield _Leftover(Finding("leftover", _rel(ws, p), "temporary folder of an interrupted write"), _remover(p))
        else:
            yield Finding("note", _rel(ws, p), "being written by a live process")
    for p in sorted(ws.root.rglob(f".*{TMP_SUFFIX}")):
        if tmp_root in p.parents or not p.is_file():
            continue
        if _unheld(p):
            yield _Leftover(
                Finding("leftover", _rel(ws, p), "temporary file of an interrupted atomic write"), _remover(p)
            )
        else:
            yield Finding("note", _rel(ws, p), "being written by a live process")


def _claim_leftovers(ws: Workspace) -> Iterator[_Leftover]:
    """Session claims (`.sessions/<key>`) whose recording never landed, and whose lock nobody holds."""
    d = ws.root / ".sessions"
    for p in sorted(d.iterdir()) if d.is_dir() else []:
        if p.name.startswith(".") or not p.is_file():
            continue
        if is_locked(ws.locks_dir / f"session-{p.name}.lock"):
            continue
        try:
            rid = p.read_text().strip()
        except OSError:
            continue
        if not ws.has_recording(rid):
            yield _Leftover(
                Finding(
                    "leftover", _rel(ws, p), f"claim of an ingest that died before storing {rid or 'its recording'}"
                ),
                _remover(p),
            )


# --- recordings and rejections ------------------------------------------------------------------


def _read_whole(path: Path, schema: Schema) -> Any:
    """Read a Parquet file completely (every page decoded) and validate it; the frame."""
    df = pq.read_table(path).to_pandas()
    validate(df, schema)
    return df


def _check_recording(ws: Workspace, folder: Path) -> Iterator[Finding | _Leftover]:
    rel = _rel(ws, folder)
    frames: dict[str, Any] = {}
    for name, schema in RECORDING_FILES.items():
        path = folder / name
        if not path.exists():
            yield Finding("problem", f"{rel}/{name}", "missing")
            continue
        try:
            frames[name] = _read_whole(path, schema)
        except (OSError, ValueError, SchemaError) as exc:
            yield _Leftover(
                Finding(
                    "problem",
                    f"{rel}/{name}",
                    f"unreadable or off-schema ({_first_line(exc)}); the recording can be set aside in {QUARANTINE}/",
                ),
                _quarantiner(ws, folder),
                verb=f"moved to {QUARANTINE}/",
            )
            return
    meta = frames.get("meta.parquet")
    if meta is None:
        return
    if len(meta) != 1:
        yield Finding("problem", f"{rel}/meta.parquet", f"{len(meta)} rows, expected 1")
        return
    row = meta.iloc[0]
    if str(row["recording_id"]) != folder.name:
        yield Finding("problem", rel, f"meta says recording {row['recording_id']}, folder is {folder.name}")
    ego = frames.get("ego.parquet")
    if ego is not None and int(row["n_samples"]) != len(ego):
        yield Finding(
            "problem", f"{rel}/ego.parquet", f"{len(ego)} samples, the catalogue says {int(row['n_samples'])}"
        )
    source = Path(str(row["source_path"]))
    if source.is_file():
        data = source.read_bytes()
        digest = content_id(data)
        if folder.name not in (digest, legacy_content_id(data)):
            yield Finding("note", rel, f"its source {source} changed since it was ingested (content hash {digest})")


def _stored_ids(ws: Workspace) -> set[str]:
    d = ws.recordings_dir
    return {f.parent.name for f in d.glob("*/meta.parquet")} if d.is_dir() else set()


def _check_recordings(ws: Workspace) -> Iterator[Finding | _Leftover]:
    d = ws.recordings_dir
    before = _stored_ids(ws)
    sessions: dict[tuple[str, str], str] = {}
    for folder in sorted(d.iterdir()) if d.is_dir() else []:
        if folder.name.startswith("."):
            continue
        if not folder.is_dir():
            yield Finding("problem", _rel(ws, folder), "a file where a recording folder is expected")
            continue
        found = list(_check_recording(ws, folder))
        yield from found
        if any(isinstance(f, _Leftover) for f in found):  # damaged: its ids are not to be trusted
            continue
        try:
            meta = pq.read_table(folder / "meta.parquet", columns=["driver_id", "session_id"]).to_pylist()[0]
        except (OSError, ValueError, IndexError):
            continue
        key = (str(meta["driver_id"]), str(meta["session_id"]))
        if key in sessions:
            yield Finding(
                "problem",
                _rel(ws, folder),
                f"driver {key[0]} session {key[1]} is stored twice (also as recording {sessions[key]})",
            )
        sessions[key] = folder.name
    try:
        cat = ws.recordings()
    except Exception as exc:  # the catalogue query itself: whatever DuckDB raises is a problem to report
        yield Finding("problem", "recordings", f"the catalogue cannot be read ({_first_line(exc)})")
        return
    listed = set(cat["recording_id"].astype(str))
    stored = _stored_ids(ws)  # after the catalogue: a recording landing meanwhile is in both or only here
    for rid in sorted(listed - stored):
        yield Finding("problem", f"recordings/{rid}", "in the catalogue but its folder is gone")
    damaged = {Path(p).parent.name for p in ws.damaged}  # named above, file by file
    for rid in sorted(set(before) - listed - damaged):
        yield Finding("problem", f"recordings/{rid}", "a stored recording the catalogue does not list")
    for p in sorted(ws.rejected_dir.glob("*.json")) if ws.rejected_dir.is_dir() else []:
        try:
            row = _read_json(p)
            validate(pd.DataFrame([row]), REJECTED)
        except (OSError, ValueError, SchemaError) as exc:
            yield Finding("problem", _rel(ws, p), f"unreadable rejection record ({_first_line(exc)})")
            continue
        if row.get("content_hash") and row["content_hash"] in stored:
            yield _Leftover(
                Finding(
                    "leftover",
                    _rel(ws, p),
                    f"rejection of content since ingested as recording "
                    f"{row['content_hash']} (an ingest stopped before forgetting it)",
                ),
                _remover(p),
            )


# --- stage tables and cross-validations -----------------------------------------------------


def _check_stage(ws: Workspace, folder: Path) -> Iterator[Finding | _Leftover]:
    try:
        _read_json(folder / "meta.json")
    except (OSError, ValueError) as exc:
        yield Finding("problem", f"{_rel(ws, folder)}/meta.json", f"unreadable ({_first_line(exc)})")
    for path in sorted(folder.glob("*.parquet")):
        schema = STAGE_SCHEMAS.get((folder.name, path.stem))
        try:
            df = pq.read_table(path).to_pandas()
            if schema is not None:
                validate(df, schema)
        except (OSError, ValueError, SchemaError) as exc:
            yield _Leftover(
                Finding(
                    "problem",
                    _rel(ws, path),
                    f"unreadable or off-schema ({_first_line(exc)}); it can be set aside in {QUARANTINE}/",
                ),
                _quarantiner(ws, path),
                verb=f"moved to {QUARANTINE}/",
            )


def _check_crossvals(ws: Workspace) -> Iterator[Finding | _Leftover]:
    d = ws.root / "crossval"
    for folder in sorted(d.iterdir()) if d.is_dir() else []:
        if folder.name.startswith("."):
            continue
        if not (folder / "result.json").exists():
            yield _Leftover(
                Finding("leftover", _rel(ws, folder), "unfinished cross-validation (no result.json)"), _remover(folder)
            )
            continue
        try:
            _read_json(folder / "result.json")
            for path in folder.glob("*.parquet"):
                pq.read_table(path)
        except (OSError, ValueError) as exc:
            yield Finding("problem", _rel(ws, folder), f"unreadable ({_first_line(exc)})")


# --- training runs -----------------------------------------------------------------------------


def _metric_episodes(path: Path) -> tuple[list[int], int]:
    """Episode numbers of metrics.jsonl and how many lines are not whole JSON."""
    episodes, bad = [], 0
    if path.exists():
        for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
            try:
                episodes.append(int(json.loads(line)["episode"]))
            except (ValueError, KeyError, TypeError):
                bad += 1
    return episodes, bad


def _torch_file(path: Path) -> tuple[Any, str | None]:
    import torch  # only when a run has a checkpoint or weights

    try:
        return torch.load(path, weights_only=True), None
    except Exception as exc:  # torch raises many kinds for a damaged file: each is a problem to report
        return None, _first_line(exc)


def _checkpoint_episode(ckpt: Any) -> int | None:
    """Episodes done at a trainer checkpoint (`DQNTrainer.state_dict`), None when it does not say."""
    try:
        return int(ckpt["counters"]["episodes_done"])
    except (KeyError, TypeError, ValueError):
        return None


def _check_run(ws: Workspace, folder: Path) -> Iterator[Finding | _Leftover]:
    from rl.runs import RUN_LOCK, RUN_STATES, run_state

    rel = _rel(ws, folder)
    if is_locked(folder / RUN_LOCK):
        yield Finding("note", rel, "being trained by a live process: not checked")
        return
    if not (folder / "config.json").exists():
        others = [p for p in folder.iterdir() if p.name != RUN_LOCK and not p.name.endswith(TMP_SUFFIX)]
        if others:
            yield Finding("problem", rel, f"no config.json but {len(others)} other file(s)")
        else:
            yield _Leftover(
                Finding("leftover", rel, "empty run folder of a training that died at its start"), _remover(folder)
            )
        return
    try:
        config = _read_json(folder / "config.json")
        trees = config.get("learner", "dqn") == "trees"  # fitted in one go: its status counts Q functions fitted
        dqn = config["auto"]["dqn"] if config.get("learner") == "auto" else config.get("dqn")  # 'auto': killed
        total = int(config["trees"]["iterations"]) + 1 if trees else int(dqn["episodes"])  # while choosing
    except (OSError, ValueError, KeyError, TypeError) as exc:
        yield Finding("problem", f"{rel}/config.json", f"unreadable ({_first_line(exc)})")
        return
    status: dict[str, Any] = {}
    if (folder / "status.json").exists():
        try:
            status = _read_json(folder / "status.json")
        except (OSError, ValueError) as exc:
            yield Finding("problem", f"{rel}/status.json", f"unreadable ({_first_line(exc)})")
            return
        if status.get("state") not in RUN_STATES:
            yield Finding("problem", f"{rel}/status.json", f"unknown state {status.get('state')!r}")
    state = run_state(folder, status)
    episodes, bad = _metric_episodes(folder / "metrics.jsonl")
    if episodes != sorted(set(episodes)):
        yield Finding("problem", f"{rel}/metrics.jsonl", "episodes repeated or out of order")
    ckpt_episode = None
    if (folder / "checkpoint.pt").exists():
        ckpt, err = _torch_file(folder / "checkpoint.pt")
        if err:
            yield Finding("problem", f"{rel}/checkpoint.pt", f"unreadable ({err})")
        else:
            ckpt_episode = _checkpoint_episode(ckpt)
            if ckpt_episode is not None and ckpt_episode > (max(episodes) if episodes else 0):
                yield Finding(
                    "problem",
                    f"{rel}/metrics.jsonl",
                    f"ends at episode {max(episodes) if episodes else 0}, the checkpoint is at {ckpt_episode}",
                )
    if (folder / "weights.pt").exists():
        _, err = _torch_file(folder / "weights.pt")
        if err:
            yield Finding("problem", f"{rel}/weights.pt", f"unreadable ({err})")
    if state == "interrupted" and trees:
        yield Finding(
            "note",
            rel,
            f"tree fit interrupted: `laneprint train --resume {folder.name}` fits it again with the run's settings",
        )
        return
    if state == "interrupted":
        frm = f"its checkpoint at episode {ckpt_episode}" if ckpt_episode is not None else "the start (no checkpoint)"
        tail = f"; {bad} half-written metrics line(s), dropped on resume" if bad else ""
        yield Finding(
            "note",
            rel,
            f"training interrupted at episode {status.get('episode', 0)}: "
            f"`laneprint train --resume {folder.name}` continues from {frm}{tail}",
        )
        return
    if bad:
        yield Finding("problem", f"{rel}/metrics.jsonl", f"{bad} line(s) that are not whole JSON")
    if state == "done":
        if not (folder / "weights.pt").exists():
            yield Finding("problem", rel, "state done but no weights.pt")
        if int(status.get("episode", -1)) != total or (episodes and max(episodes) != total):
            yield Finding(
                "problem",
                rel,
                f"state done at episode {status.get('episode')} "
                f"(metrics to {max(episodes) if episodes else 0}) of {total}",
            )


def _check_runs(ws: Workspace) -> Iterator[Finding | _Leftover]:
    d = ws.runs_dir
    for folder in sorted(d.iterdir()) if d.is_dir() else []:
        if folder.is_dir() and not folder.name.startswith("."):
            yield from _check_run(ws, folder)


# --- the whole workspace ----------------------------------------------------------------------------


def _stage_folders(ws: Workspace) -> list[Path]:
    return sorted(p.parent for p in ws.root.glob("*/meta.json") if p.parent.name not in ("runs", "crossval"))


def check_workspace(ws: Workspace, repair: bool = False) -> dict[str, Any]:
    """Check every part of `ws`; with `repair`, remove the leftovers found. A JSON-ready report
    whose `exit_code` is 1 when a problem (or, without repair, a leftover) remains."""
    if not ws.root.is_dir():
        raise UserError(f"no workspace at {ws.root}")
    parts: list[Iterator[Finding | _Leftover]] = [
        _temp_leftovers(ws),
        _claim_leftovers(ws),
        _check_recordings(ws),
        *(_check_stage(ws, f) for f in _stage_folders(ws)),
        _check_crossvals(ws),
        _check_runs(ws),
    ]
    findings: list[Finding] = []
    repaired: list[str] = []
    for part in parts:
        for item in part:
            if isinstance(item, _Leftover):
                if repair:
                    try:
                        item.remove()
                    except OSError as exc:  # said as it is: not removed, and why
                        findings.append(
                            Finding(
                                "problem",
                                item.finding.path,
                                f"{item.finding.message}; could not be "
                                f"{item.verb.split(' ')[0]}: {exc.strerror or exc}",
                            )
                        )
                        continue
                    repaired.append(f"{item.verb} {item.finding.path} ({item.finding.message})")
                    continue
                item = item.finding
            findings.append(item)
    counts = {k: sum(f.kind == k for f in findings) for k in ("problem", "leftover", "note")}
    return {
        "workspace": str(ws.root),
        "ok": counts["problem"] + counts["leftover"] == 0,
        "counts": counts,
        "findings": [asdict(f) for f in findings],
        "repaired": repaired,
        "n_recordings": sum(1 for _ in ws.recordings_dir.glob("*/meta.parquet")) if ws.recordings_dir.is_dir() else 0,
        "n_runs": sum(1 for p in ws.runs_dir.glob("*/config.json")) if ws.runs_dir.is_dir() else 0,
        "exit_code": 0 if counts["problem"] + counts["leftover"] == 0 else 1,
    }
