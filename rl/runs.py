"""Training runs in the workspace: `runs/<run_id>/`, written while training so a
dashboard can follow a run live.

Files of a run folder:

- ``config.json``: target, reward, reference lines used, environment and trainer
  settings, seed, code version (git commit), data fingerprint, created_at;
- ``status.json`` (atomic): state running/done/failed/cancelled, pid, episode,
  episodes, started_at, updated_at, message;
- ``run.lock``: flock-ed by the training process for as long as it lives; a status
  'running' whose lock nobody holds is a run that was killed: `run_state` calls it
  'interrupted' (resume it with `laneprint train --resume RUN_ID`);
- ``metrics.jsonl``: one JSON line per finished episode, flushed as written;
- ``checkpoint.pt``: everything to resume (`laneprint train --resume RUN_ID`);
- ``weights.pt``: the Q network's state dict (load with ``weights_only=True``);
- ``evaluation.json`` + ``eval_states.parquet``, ``eval_changes.parquet``.
"""

from __future__ import annotations

import io
import json
import os
import re
import signal
import subprocess
import time
from contextlib import ExitStack
from dataclasses import asdict, dataclass, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import pandas as pd
import torch

from laneprint.errors import SettingError, UserError
from laneprint.locks import FileLock, is_locked
from laneprint.progress import ProgressFn, report
from laneprint.provenance import analysis_mark
from laneprint.workspace import Workspace, atomic_write_bytes, atomic_write_json
from rl.learners.dqn import DQNSettings, DQNTrainer, q_network
from rl.problem.env import Approach, EnvConfig, LaneChangeDecisionEnv, approaches_from_decisions, observation_names
from rl.evaluation.evaluate import FIELDS as EVAL_FIELDS, agent_policy, evaluate_policies, greedy_policy
from rl.baselines.imitation import fitted_classifier
from rl.problem.rewards import ReferenceLines
from rl.settings import AutoSettings, LearnerSettings, TreeQSettings, learner_config, stored_learner

RUN_STATES = ("running", "done", "failed", "cancelled", "interrupted")
RUN_LOCK = "run.lock"


@dataclass(frozen=True)
class Target:
    """Whom an agent imitates: a style (its typical driver's lines) or one driver."""

    kind: str  # 'style' or 'driver'
    name: str  # style name or driver id

    @property
    def label(self) -> str:
        return f"{self.kind} {self.name}"


def now_iso() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def new_run_id(target: Target, reward: str, seed: int) -> str:
    """A readable, sortable run id, e.g. ``20261122-013000-normal-timing-s0``."""
    slug = re.sub(r"[^a-z0-9]+", "-", target.name.lower()).strip("-") or "run"
    return f"{datetime.now(timezone.utc):%Y%m%d-%H%M%S}-{slug}-{reward}-s{seed}"


def code_version() -> dict[str, Any]:
    """Package version and git commit of the code (None when not in a git checkout)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        pkg = version("laneprint")
    except PackageNotFoundError:  # pragma: no cover
        pkg = None
    commit, dirty = None, None
    try:
        here = Path(__file__).resolve().parent
        commit = (
            subprocess.run(
                ["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=5
            ).stdout.strip()
            or None
        )
        dirty = bool(
            subprocess.run(
                ["git", "status", "--porcelain", "--", "rl"], cwd=here.parent, capture_output=True, text=True, timeout=5
            ).stdout.strip()
        )
    except (OSError, subprocess.SubprocessError):
        pass
    return {"laneprint": pkg, "git_commit": commit, "rl_dirty": dirty, "torch": torch.__version__}


def resolve_lines(workspace: Workspace, target: Target, lines: str) -> ReferenceLines:
    """The reference lines to train on: the analysis's (default) or Table 1 (`lines='paper'`)."""
    if lines == "paper":
        if target.kind != "style":
            raise SettingError("{0} paper needs {1} (Table 1 has the three typical drivers only)", "lines", "style")
        return ReferenceLines.paper(target.name)
    if lines != "analysis":
        raise SettingError(f"unknown {{0}} {lines!r}: choose 'analysis' or 'paper'", "lines")
    if not workspace.has_table("analysis", "reference_lines"):
        raise UserError(f"no analysis in {workspace.root}: run `laneprint analyze` first or pass --lines paper")
    table = workspace.read_table("analysis", "reference_lines")
    if target.kind == "style":
        return ReferenceLines.from_table(table, style=target.name)
    return ReferenceLines.from_table(table, driver=target.name)


# --- run folder I/O ------------------------------------------------------------------


def run_dir(workspace: Workspace, run_id: str) -> Path:
    return workspace.runs_dir / run_id


def run_state(folder: Path, status: dict[str, Any] | None) -> str | None:
    """The run's state as shown to users: status.json's, except that 'running' with no live
    process holding the run's lock is 'interrupted' (killed; resumable from its checkpoint), and a
    run with no status yet is 'starting' (its lock held) or 'interrupted'."""
    state = (status or {}).get("state")
    if state == "running" and not is_locked(folder / RUN_LOCK):
        return "interrupted"
    if state is None and (folder / "config.json").exists():  # before its first status
        return "starting" if is_locked(folder / RUN_LOCK) else "interrupted"
    return state


def mark_interrupted(folder: Path, status: dict[str, Any] | None) -> dict[str, Any] | None:
    """`status` of a run left 'running' by a process that died, written back to its status.json as
    'interrupted', so the file says what every view shows. Done under the run's own lock: never over a
    live trainer's status (a trainer that just finished wrote 'done' before dropping it: re-read)."""
    if (status or {}).get("state") != "running" or is_locked(folder / RUN_LOCK):
        return status
    lock = FileLock(folder / RUN_LOCK)
    try:
        if not lock.acquire(blocking=False):
            return status
    except OSError:  # a workspace that cannot be written: the views still say interrupted
        return status
    try:
        current = _read_json(folder / "status.json")
        if not current or current.get("state") != "running":
            return current or status
        current = dict(
            current,
            state="interrupted",
            message=(
                f"interrupted at episode {current.get('episode', 0)} (its process died); "
                f"resume it with `laneprint train --resume {folder.name}`"
            ),
        )
        try:
            atomic_write_json(folder / "status.json", current)
        except OSError:
            pass
        return current
    finally:
        lock.release()


def lock_run(folder: Path, run_id: str) -> FileLock:
    """Hold the run's lock for this process's lifetime of the run; refuse a run trained elsewhere."""
    lock = FileLock(folder / RUN_LOCK)
    if not lock.acquire(blocking=False):
        raise UserError(f"run {run_id!r} is being trained by another process right now")
    return lock


def _save_torch(path: Path, obj: Any) -> None:
    buf = io.BytesIO()
    torch.save(obj, buf)
    atomic_write_bytes(path, buf.getvalue())


class RunWriter:
    """Writes status, metrics and checkpoints of one run."""

    def __init__(self, folder: Path, episodes: int, started_at: str | None = None) -> None:
        self.folder = folder
        self.episodes = episodes
        self.started_at = started_at or now_iso()
        self._last_status = 0.0
        self.extra: dict[str, Any] = {}  # written into every status (a personalisation's phase)
        self._metrics = open(folder / "metrics.jsonl", "a", encoding="utf-8")

    def status(self, state: str, episode: int, message: str = "", force: bool = True) -> None:
        if not force and time.monotonic() - self._last_status < 0.5:
            return
        self._last_status = time.monotonic()
        atomic_write_json(
            self.folder / "status.json",
            {
                "state": state,
                "pid": os.getpid(),
                "episode": int(episode),
                "episodes": int(self.episodes),
                "started_at": self.started_at,
                "updated_at": now_iso(),
                "message": message,
                **self.extra,
            },
        )

    def metric(self, row: dict[str, Any]) -> None:
        self._metrics.write(json.dumps(row) + "\n")

    def flush(self) -> None:
        self._metrics.flush()

    def close(self) -> None:
        self._metrics.close()


def _truncate_metrics(path: Path, episodes_done: int) -> None:
    """Drop metrics lines written after the checkpoint a run resumes from."""
    if not path.exists():
        return
    keep = []
    for line in path.read_text(encoding="utf-8").splitlines():
        try:
            if json.loads(line)["episode"] <= episodes_done:
                keep.append(line)
        except (ValueError, KeyError):
            continue
    atomic_write_bytes(path, ("\n".join(keep) + ("\n" if keep else "")).encode())


class _ChoiceCancelled(Exception):
    """SIGTERM or SIGINT while the default learner is being chosen."""


class _StopFlag:
    """Set by SIGTERM/SIGINT so the loop can checkpoint and exit cleanly."""

    def __init__(self) -> None:
        self.signal: int | None = None
        self._old: dict[int, Any] = {}

    def __enter__(self) -> "_StopFlag":
        for sig in (signal.SIGTERM, signal.SIGINT):
            try:
                self._old[sig] = signal.signal(sig, self._handle)
            except ValueError:  # not the main thread: no signal handling
                pass
        return self

    def _handle(self, signum: int, frame: Any) -> None:
        self.signal = signum

    def __exit__(self, *exc: Any) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)

    def __call__(self) -> bool:
        return self.signal is not None


def create_run(
    workspace: Workspace,
    target: Target,
    env_config: EnvConfig,
    settings: LearnerSettings,
    *,
    run_id: str | None = None,
    lines_source: str = "analysis",
    extra: dict[str, Any] | None = None,
    held: ExitStack | None = None,
) -> tuple[Path, dict[str, Any]]:
    """Make a new run folder with its config.json; returns (folder, config). With `held`, the
    run's lock is taken (before config.json appears) and released when `held` closes."""
    run_id = run_id or new_run_id(target, env_config.reward.name, settings.seed)
    if not re.fullmatch(r"[A-Za-z0-9._-]+", run_id):
        raise UserError(f"run id {run_id!r}: use letters, digits, '.', '_' or '-'")
    folder = run_dir(workspace, run_id)
    if (folder / "config.json").exists():
        raise UserError(f"run {run_id!r} exists already (pass --resume {run_id} to continue it)")
    folder.mkdir(parents=True, exist_ok=True)
    if held is not None:
        held.callback(lock_run(folder, run_id).release)
        if (folder / "config.json").exists():  # created by a concurrent `train --run-id` meanwhile
            raise UserError(f"run {run_id!r} exists already (pass --resume {run_id} to continue it)")
    config = {
        "run_id": run_id,
        "target": asdict(target),
        "reward": env_config.reward.name,
        "lines_source": lines_source,
        "lines": env_config.lines.to_dict(),
        "seed": settings.seed,
        "env": env_config.to_dict(),
        **learner_config(settings),
        "created_at": now_iso(),
        **(extra or {}),
    }
    # a fleet passes these once for all its runs (each costs a git call or a folder scan)
    config.setdefault("code_version", code_version())
    config.setdefault("data_fingerprint", workspace.fingerprint())
    # the analysis the run's lines and drivers came from (`laneprint.provenance`)
    config.setdefault("analysis_fingerprint", workspace.analysis_fingerprint())
    atomic_write_json(folder / "config.json", config)
    return folder, config


def train_run(
    workspace: Workspace,
    target: Target | None,
    env_config: EnvConfig | None,
    settings: LearnerSettings | None,
    *,
    run_id: str | None = None,
    lines_source: str = "analysis",
    resume: str | None = None,
    episodes: int | None = None,
    evaluate: bool = True,
    progress: ProgressFn | None = None,
) -> dict[str, Any]:
    """Train (or resume) one run in the workspace; returns a JSON-ready summary.

    `episodes` on a resume changes the run's total (its epsilon schedule follows); a
    run killed before its first checkpoint resumes from the start with its own config.
    The run's lock (`run.lock`) is held until this returns, so a killed run shows as
    'interrupted' (`run_state`) and two processes never train one run.

    On SIGTERM/SIGINT the run saves a checkpoint and ends with state 'cancelled'.
    """
    with ExitStack() as held:
        return _train_run(
            workspace,
            target,
            env_config,
            settings,
            held,
            run_id=run_id,
            lines_source=lines_source,
            resume=resume,
            episodes=episodes,
            evaluate=evaluate,
            progress=progress,
        )


def _train_run(
    workspace: Workspace,
    target: Target | None,
    env_config: EnvConfig | None,
    settings: LearnerSettings | None,
    held: ExitStack,
    *,
    run_id: str | None,
    lines_source: str,
    resume: str | None,
    episodes: int | None,
    evaluate: bool,
    progress: ProgressFn | None,
) -> dict[str, Any]:
    workspace.ensure()
    chose = False  # `auto` chose its learner in this call (the DQN it kept is checkpoint.pt, its episodes written)
    if resume:
        folder = run_dir(workspace, resume)
        if not (folder / "config.json").exists():
            raise UserError(f"no run {resume!r} in {workspace.root}")
        held.callback(lock_run(folder, resume).release)
        config = json.loads((folder / "config.json").read_text())
        if config.get("kind") == "personalized":  # its K decisions and base are not a driver run's data
            raise UserError(f"run {resume!r} was personalised: run `laneprint personalize` again instead")
        run_id = resume
        target = Target(**config["target"])
        env_config = EnvConfig.from_dict(config["env"])
        restarted = config.get("learner", "dqn") != "dqn"
        if restarted:  # a learner choice or a tree fit: both go in one go,
            config.setdefault("resumed_at", []).append(now_iso())  # so they start over with the run's settings
            atomic_write_json(folder / "config.json", config)
            settings = stored_learner(config)
            if isinstance(settings, AutoSettings):
                settings, env_config = _choose_learner(
                    workspace, folder, config, target, env_config, settings, progress
                )
                chose = True
            if isinstance(settings, TreeQSettings):
                return _fit_tree_run(workspace, folder, config, target, env_config, settings, evaluate, progress)
        settings = DQNSettings.from_dict(config["dqn"])
        if episodes is not None and episodes != settings.episodes:
            settings = replace(settings, episodes=episodes)
            config["dqn"]["episodes"] = episodes
        if not restarted:
            config.setdefault("resumed_at", []).append(now_iso())
        atomic_write_json(folder / "config.json", config)
        # killed before its first checkpoint: start over with the run's own settings
        state = torch.load(folder / "checkpoint.pt", weights_only=True) if (folder / "checkpoint.pt").exists() else None
        old_status = json.loads((folder / "status.json").read_text()) if (folder / "status.json").exists() else {}
        started_at = old_status.get("started_at")
    else:
        assert target is not None and env_config is not None and settings is not None
        folder, config = create_run(
            workspace, target, env_config, settings, run_id=run_id, lines_source=lines_source, held=held
        )
        run_id = config["run_id"]
        state, started_at = None, None
        if isinstance(settings, AutoSettings):
            settings, env_config = _choose_learner(workspace, folder, config, target, env_config, settings, progress)
            chose = True
            if isinstance(settings, DQNSettings):  # the DQN the choice trained, as `_choose_learner` saved it
                state = torch.load(folder / "checkpoint.pt", weights_only=True)
        if isinstance(settings, TreeQSettings):
            return _fit_tree_run(workspace, folder, config, target, env_config, settings, evaluate, progress)

    approaches = None
    if env_config.scenes == "recorded":
        approaches = recorded_approaches(workspace, target)
        config.setdefault("scene_decisions", len(approaches))
    trainer = DQNTrainer(env_config, settings, approaches=approaches)
    if trainer.settings != settings:  # episodes fixed by the number of recorded approaches
        settings = trainer.settings
        config["dqn"] = settings.to_dict()
        atomic_write_json(folder / "config.json", config)
    if state is not None:
        trainer.load_state_dict(state)
    resumed_from = 0 if chose else trainer.episodes_done
    if resume:
        _truncate_metrics(folder / "metrics.jsonl", trainer.episodes_done)
    writer = RunWriter(folder, settings.episodes, started_at)
    writer.status("running", trainer.episodes_done, "resumed" if resume and not chose else "training")

    def checkpoint(t: DQNTrainer) -> None:
        writer.flush()
        _save_torch(folder / "checkpoint.pt", t.state_dict())

    def on_episode(row: dict[str, Any]) -> None:
        writer.metric(row)

    def on_vector_step(t: DQNTrainer) -> bool:
        writer.flush()
        writer.status("running", t.episodes_done, "training", force=False)
        report(progress, t.episodes_done, settings.episodes, f"{target.label}: episode {t.episodes_done}")
        return False

    final = "done"
    message = ""
    try:
        with _StopFlag() as stop:
            trainer.train(
                on_episode=on_episode, should_stop=stop, on_checkpoint=checkpoint, on_vector_step=on_vector_step
            )
        if stop.signal is not None:
            final, message = "cancelled", f"stopped by signal {signal.Signals(stop.signal).name}"
    except Exception as exc:
        writer.flush()
        checkpoint(trainer)
        writer.status("failed", trainer.episodes_done, f"{type(exc).__name__}: {exc}")
        writer.close()
        raise
    checkpoint(trainer)
    _save_torch(folder / "weights.pt", trainer.policy_net.state_dict())
    writer.status(
        final if final != "done" else "running",
        trainer.episodes_done,
        message or ("evaluating" if evaluate else "done"),
    )
    result: dict[str, Any] = {
        "run_id": run_id,
        "folder": str(folder),
        "state": final,
        "learner": "dqn",
        "episodes": trainer.episodes_done,
        "env_steps": trainer.env_steps,
        "wall_s": round(trainer.wall_s, 2),
        "target": target.label,
        "reward": env_config.reward.name,
        "message": message,
    }
    if resume:
        result["resumed_from_episode"] = resumed_from
    if config.get("learner_choice"):
        result["learner_choice"] = config["learner_choice"]
    if trainer.env_steps < settings.learning_starts:  # the replay memory never filled: no update was made
        result["warning"] = (
            f"the agent never learnt: {trainer.env_steps:,} transitions in {trainer.episodes_done:,} "
            f"episodes, and learning starts after {settings.learning_starts:,}; train more episodes "
            "(or lower --learning-starts)"
        )
    if final == "done" and evaluate:
        try:
            ev = evaluate_run(workspace, run_id)
            result["evaluation"] = ev.get("summary_typical") or ev.get("summary")
            result["evaluation_note"] = ev.get("note", "")
        except UserError as exc:
            result["evaluation_note"] = str(exc)
    writer.status(final, trainer.episodes_done, message or "done")
    writer.close()
    return result


def _choose_learner(
    workspace: Workspace,
    folder: Path,
    config: dict[str, Any],
    target: Target,
    env_config: EnvConfig,
    settings: AutoSettings,
    progress: ProgressFn | None,
) -> tuple[DQNSettings | TreeQSettings, EnvConfig]:
    """`--learner auto`: choose across inner folds of the target's sessions (`rl.learners.choice`); the run's
    config then names the chosen learner (its settings and environment) and keeps the choice.

    Returns (settings, environment). When the DQN is chosen, the one trained in one batch with the inner
    folds' DQNs is the run's: its metrics lines and its state (`checkpoint.pt`) are written before the
    config names the DQN, and the run goes on from that checkpoint. The run's status follows the choice's
    phases (inner folds, scenes, training, evaluation) with its summed episodes.
    """
    from rl.learners.choice import ChoiceTask, choose_and_fit
    from rl.problem.env import learner_env

    writer = RunWriter(folder, 1)
    writer.status("running", 0, "choosing the learner: reading the target's approaches")

    def phase(done: int, total: int, message: str) -> None:
        writer.episodes = total
        writer.status("running", done, message, force=False)
        report(progress, done, total, f"{target.label}: {message}")

    def cancel(signum: int, frame: Any) -> None:  # nothing to checkpoint yet: the choice stops where it is
        raise _ChoiceCancelled

    handlers = {}
    for sig in (signal.SIGTERM, signal.SIGINT):
        try:
            handlers[sig] = signal.signal(sig, cancel)
        except ValueError:  # not the main thread: no signal handling
            pass
    try:
        fitted = choose_and_fit(
            [ChoiceTask(recorded_approaches(workspace, target), env_config, settings, target.label)],
            phase,
            fit_trees=False,
        )[0]
    except _ChoiceCancelled:
        writer.status("cancelled", 0, "cancelled while choosing the learner")
        raise SystemExit(130) from None
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
        writer.close()
    choice = fitted.choice
    chosen, env = fitted.settings, learner_env(env_config, choice.learner)
    if choice.learner == "dqn":  # its episodes, then its state, before the config names the DQN: a run killed
        # from then on resumes from the very DQN the choice trained (a `DQNTrainer` trained again from the start
        # computes it only up to floating-point summation order); killed before, it chooses again
        atomic_write_bytes(folder / "metrics.jsonl", "".join(json.dumps(r) + "\n" for r in fitted.rows).encode())
        _save_torch(folder / "checkpoint.pt", fitted.dqn_state)
    config.update(learner_config(chosen), env=env.to_dict(), learner_choice=choice.to_dict())
    atomic_write_json(folder / "config.json", config)
    return chosen, env


def _fit_tree_run(
    workspace: Workspace,
    folder: Path,
    config: dict[str, Any],
    target: Target,
    env_config: EnvConfig,
    settings: TreeQSettings,
    evaluate: bool,
    progress: ProgressFn | None,
) -> dict[str, Any]:
    """`train_run` with the tree learner: fitted Q iteration on the target's recorded approaches, in one go
    (its status counts fitted Q functions instead of episodes; a killed fit is 'interrupted', fit it again)."""
    from rl.learners.trees import fit_tree_q

    approaches = recorded_approaches(workspace, target)
    config["scene_decisions"] = len(approaches)
    atomic_write_json(folder / "config.json", config)
    total = settings.iterations + 1
    writer = RunWriter(folder, total)
    writer.status("running", 0, "fitting the tree Q functions")
    t0 = time.perf_counter()

    def step(done: int, _total: int, label: str) -> None:
        writer.status("running", done, label)
        report(progress, done, total, f"{target.label}: {label}")

    try:
        net = fit_tree_q(approaches, env_config, settings, progress=step, label="tree Q fitted")
    except BaseException as exc:
        writer.status("failed", 0, f"{type(exc).__name__}: {exc}")
        writer.close()
        raise
    _save_torch(folder / "weights.pt", net.state_dict())
    result: dict[str, Any] = {
        "run_id": config["run_id"],
        "folder": str(folder),
        "state": "done",
        "learner": "trees",
        "episodes": 0,
        "env_steps": 0,
        "wall_s": round(time.perf_counter() - t0, 2),
        "target": target.label,
        "reward": env_config.reward.name,
        "message": "",
    }
    if config.get("learner_choice"):
        result["learner_choice"] = config["learner_choice"]
    if evaluate:
        writer.status("running", total, "evaluating")
        try:
            ev = evaluate_run(workspace, config["run_id"])
            result["evaluation"] = ev.get("summary_typical") or ev.get("summary")
            result["evaluation_note"] = ev.get("note", "")
        except UserError as exc:
            result["evaluation_note"] = str(exc)
    writer.status("done", total, "done")
    writer.close()
    return result


# --- evaluation of a run ----------------------------------------------------------------


def _load_q(folder: Path, settings: LearnerSettings, env: EnvConfig) -> torch.nn.Module:
    path = folder / "weights.pt"
    if not path.exists():
        raise UserError(f"run {folder.name!r} has no weights yet (still training or failed)")
    state = torch.load(path, weights_only=True)
    if isinstance(settings, TreeQSettings):
        from rl.learners.trees import TreeQNetwork

        return TreeQNetwork.from_state_dict(state).eval()
    assert isinstance(settings, DQNSettings)  # an `auto` run names its chosen learner before it has weights
    net = q_network(settings.hidden, len(observation_names(env)))
    net.load_state_dict(state)
    net.eval()
    return net


def target_drivers(workspace: Workspace, target: Target) -> tuple[list[str], str | None]:
    """Drivers whose decisions judge a run: the driver, or a style's members (typical first)."""
    if target.kind == "driver":
        return [target.name], target.name
    if not workspace.has_table("analysis", "styles"):
        raise UserError("no analysis styles table: run `laneprint analyze` first")
    styles = workspace.read_table("analysis", "styles")
    members = styles[styles["style"].str.lower() == target.name.lower()]
    if members.empty:
        raise UserError(f"no drivers of style {target.name!r} in the analysis")
    typical = members.loc[members["is_typical"].astype(bool), "driver_id"].astype(str).tolist()
    rest = sorted(set(members["driver_id"].astype(str)) - set(typical))
    return typical + rest, (typical[0] if typical else None)


def personalized_split(decisions: pd.DataFrame, drivers: list[str], given: list[str]) -> dict[str, Any]:
    """A personalised run's split of its driver's rows: `given`, the K decisions it was built from (press and
    not-yet rows), and `scored`, the decisions it did not see, or the K themselves when it saw all of them;
    `scored_on` says which ("held out: the N decisions not given" or "in-sample: all K decisions given")."""
    rows = decisions[decisions["driver_id"].astype(str).isin(drivers)]
    ids = rows["decision_id"].astype(str)
    given_set = set(given)
    given_rows, rest = rows[ids.isin(given_set)], rows[~ids.isin(given_set)]
    n_rest = int(rest.loc[rest["label"] == "change", "decision_id"].nunique())
    if n_rest:
        scored, what = rest, f"held out: the {n_rest} decisions not given"
    else:
        scored, what = given_rows, f"in-sample: all {len(given)} decisions given"
    return {
        "given": given_rows,
        "scored": scored,
        "scored_on": what,
        "counts": {"given": len(given), "held_out": n_rest},
    }


def evaluate_run(
    workspace: Workspace, run_id: str, decisions: pd.DataFrame | None = None, classifiers: dict | None = None
) -> dict[str, Any]:
    """Evaluate a run against the drivers' recorded decisions; writes evaluation.json + tables.

    A fleet evaluates all its agents on one copy of the analysis `decisions` table and
    one `classifiers` cache (a driver's imitation classifier fitted once for all its seeds).
    """
    folder = run_dir(workspace, run_id)
    if not (folder / "config.json").exists():
        raise UserError(f"no run {run_id!r} in {workspace.root}")
    config = json.loads((folder / "config.json").read_text())
    target = Target(**config["target"])
    cfg = EnvConfig.from_dict(config["env"])
    settings = stored_learner(config)
    net = _load_q(folder, settings, cfg)
    if decisions is None:
        if not workspace.has_table("analysis", "decisions"):
            raise UserError(
                f"no analysis in {workspace.root}: run `laneprint analyze` first to evaluate against the drivers"
            )
        decisions = workspace.read_table("analysis", "decisions")
    drivers, typical = target_drivers(workspace, target)
    given = [str(d) for d in config.get("decision_ids") or []] if config.get("kind") == "personalized" else []
    split = personalized_split(decisions, drivers, given) if given else None
    if split is not None:
        decisions = split["scored"]  # the agent and its comparators are scored on these rows only
    # the imitation benchmark: fitted on the states the agent learnt from (in-sample, like the agent), or
    # for a personalised run on the same K given decisions the agent was built from
    fit_rows = split["given"] if split is not None else decisions[decisions["driver_id"].astype(str).isin(drivers)]
    member_approaches, _ = approaches_from_decisions(fit_rows)
    policies = {"agent": agent_policy(net, cfg), "greedy": greedy_policy(cfg)}
    if member_approaches:
        policies["imitation"] = fitted_classifier(
            member_approaches,
            cfg,
            settings.seed,
            classifiers,
            key=tuple(drivers) + (("given", *given) if given else ()),
        ).policy(cfg)
    out: dict[str, Any] = {
        "run_id": run_id,
        "target": asdict(target),
        "reward": cfg.reward.name,
        "drivers": drivers,
        "typical_driver": typical,
        "evaluated_at": now_iso(),
        "data_fingerprint": workspace.fingerprint(),
        "analysis_fingerprint": workspace.analysis_fingerprint(),
    }
    tables = {}
    groups = {"members": drivers}
    if typical is not None and target.kind == "style":
        groups = {"typical": [typical], "members": drivers}
    for group, ids in groups.items():
        sel = decisions[decisions["driver_id"].astype(str).isin(ids)]
        approaches, skipped = approaches_from_decisions(sel)
        ev = evaluate_policies(policies, approaches, cfg, skipped)
        out[f"summary_{group}"] = ev["summary"]
        out[f"n_decisions_{group}"] = ev["n_decisions"]
        out[f"n_states_{group}"] = ev["n_states"]
        out[f"skipped_{group}"] = ev["skipped"]
        if group == "members":
            tables = {"eval_states": ev["states"], "eval_changes": ev["changes"]}
    out["summary"] = out.get("summary_typical") or out["summary_members"]
    out["fields"] = EVAL_FIELDS
    if split is not None:
        out.update(
            {
                "scored_on": split["scored_on"],
                "split": split["counts"],
                "note": f"{split['scored_on']}: the agent was built from the driver's first {len(given)} "
                "decisions and the imitation classifier fitted on the same ones; greedy follows the "
                "style's lines. Scored on the others, which neither saw."
                if split["counts"]["held_out"]
                else f"{split['scored_on']}: every decision was given, so the figures are in-sample "
                "(the agent and the imitation classifier saw all of them).",
            }
        )
    else:
        out["scored_on"] = "in-sample"
        out["note"] = (
            "in-sample figures (the agent and the imitation classifier were fitted on these decisions; "
            "`laneprint crossval --run` holds sessions out): the typical driver's decisions first "
            "('summary_typical'), then all members'"
            if "summary_typical" in out
            else "in-sample figures on the driver's decisions (`laneprint crossval --run` holds sessions out)"
        )
    for name, df in tables.items():
        buf = io.BytesIO()
        df.to_parquet(buf, index=False)
        atomic_write_bytes(folder / f"{name}.parquet", buf.getvalue())
    atomic_write_json(folder / "evaluation.json", out)
    return out


def recorded_approaches(workspace: Workspace, target: Target) -> list["Approach"]:
    """Every recorded approach of the target: the driver's, or all members' of a style."""
    if not workspace.has_table("analysis", "decisions"):
        raise UserError(f"no analysis in {workspace.root}: recorded scenes need `laneprint analyze` first")
    decisions = workspace.read_table("analysis", "decisions")
    drivers, _ = target_drivers(workspace, target)
    approaches, _ = approaches_from_decisions(decisions[decisions["driver_id"].astype(str).isin(drivers)])
    if not approaches:
        raise SettingError(
            f"no recorded approaches for {target.label}: nothing to replay (try {{0}} synthetic)", "scenes"
        )
    return approaches


def replay_env(workspace: Workspace, target: Target, config: EnvConfig | None = None) -> "LaneChangeDecisionEnv":
    """The environment in replay mode over the recorded approaches of a driver or a style's members."""
    approaches = recorded_approaches(workspace, target)
    return LaneChangeDecisionEnv(
        config or EnvConfig(lines=resolve_lines(workspace, target, "analysis")), approaches=approaches
    )


# --- for the dashboard ----------------------------------------------------------------


def _read_json(path: Path) -> dict[str, Any] | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def read_metrics(path: Path) -> pd.DataFrame:
    """metrics.jsonl as a frame (a half-written last line is ignored)."""
    rows = []
    if path.exists():
        for line in path.read_text(encoding="utf-8").splitlines():
            try:
                rows.append(json.loads(line))
            except ValueError:
                continue
    return pd.DataFrame(rows)


def list_runs(workspace: Workspace) -> pd.DataFrame:
    """One row per run folder: id, target, reward, seed, state, progress, times, headline figures."""
    cols = [
        "run_id",
        "target_kind",
        "target",
        "reward",
        "lines_source",
        "seed",
        "state",
        "episode",
        "episodes",
        "started_at",
        "updated_at",
        "message",
        "recall",
        "balanced_accuracy",
        "timing_mae_s",
        "analysis",
        "analysis_label",
        "analysis_fingerprint",
    ]
    rows = []
    root = workspace.runs_dir
    current = workspace.analysis_fingerprint()
    for folder in sorted(root.glob("*")) if root.exists() else []:
        config = _read_json(folder / "config.json")
        if config is None:
            continue
        status = mark_interrupted(folder, _read_json(folder / "status.json")) or {}
        ev = _read_json(folder / "evaluation.json") or {}
        agent: dict[str, Any] = next((r for r in ev.get("summary", []) if r.get("who") == "agent"), {})
        rows.append(
            {
                "run_id": folder.name,
                "target_kind": config["target"]["kind"],
                "target": config["target"]["name"],
                "reward": config.get("reward"),
                "lines_source": config.get("lines_source"),
                "seed": config.get("seed"),
                "state": run_state(folder, status),
                "episode": status.get("episode"),
                "episodes": status.get("episodes"),
                "started_at": status.get("started_at"),
                "updated_at": status.get("updated_at"),
                "message": status.get("message"),
                "recall": agent.get("recall"),
                "balanced_accuracy": agent.get("balanced_accuracy"),
                "timing_mae_s": agent.get("timing_mae_s"),
                **run_analysis_mark(config, current),
            }
        )
    return pd.DataFrame(rows, columns=cols)


def run_analysis_mark(config: dict[str, Any], current: str | None) -> dict[str, str | None]:
    """Whether a run was made with the current analysis (`laneprint.provenance.analysis_mark`); a run
    trained on Table 1's lines (`--lines paper`) still took its drivers from the analysis."""
    mark = analysis_mark(config.get("analysis_fingerprint"), current)
    return {k: mark[k] for k in ("analysis", "analysis_label", "analysis_fingerprint")}


def load_run(workspace: Workspace, run_id: str) -> dict[str, Any]:
    """Everything of one run: config, status, metrics (frame), evaluation (dict or None) and its tables."""
    folder = run_dir(workspace, run_id)
    config = _read_json(folder / "config.json")
    if config is None:
        raise UserError(f"no run {run_id!r} in {workspace.root}")
    out: dict[str, Any] = {
        "run_id": run_id,
        "folder": folder,
        "config": config,
        "status": _read_json(folder / "status.json"),
        "metrics": read_metrics(folder / "metrics.jsonl"),
        "evaluation": _read_json(folder / "evaluation.json"),
        "has_weights": (folder / "weights.pt").exists(),
        "analysis_mark": analysis_mark(config.get("analysis_fingerprint"), workspace.analysis_fingerprint()),
    }
    for name in ("eval_states", "eval_changes"):
        path = folder / f"{name}.parquet"
        out[name] = pd.read_parquet(path) if path.exists() else None
    return out


def load_weights(workspace: Workspace, run_id: str) -> torch.nn.Module:
    """The run's trained Q network (weights loaded with weights_only=True)."""
    folder = run_dir(workspace, run_id)
    config = _read_json(folder / "config.json")
    if config is None:
        raise UserError(f"no run {run_id!r} in {workspace.root}")
    return _load_q(folder, stored_learner(config), EnvConfig.from_dict(config["env"]))
