"""Run one function over many items, in this process or on Ray: the one seam to Ray.

The stages never import Ray; they hand a module-level function and its items to
`run_tasks` (all results at once) or `iter_tasks` (results streamed in item order)::

    from laneprint.parallel import run_tasks

    scores = run_tasks(score_fold, folds, backend="ray", progress=progress, label="folds")

Backends (`--backend`, `laneprint.cliutil.BackendOpt`):

- ``local``: ``fn(item)`` for each item, one after another, in this process;
- ``ray``: each item is one Ray task (1 CPU) on Ray's workers. With `ray_address`
  it joins that cluster (`ray.init(address=...)`); without it, a local Ray instance
  is started with `num_cpus` (default: this machine's cores) and shut down at the
  end. A Ray instance that is already running in this process (a caller's
  `backend_session`, a test fixture) is used and left running.

Contract for `fn` and the items: `fn` is a module-level function (Ray pickles it by
reference, so the workers import its module: laneprint must be installed on them),
items and results are picklable and self-contained (a worker on another machine
sees neither this process's memory nor, unless shared, its files). Results come
back in item order whatever order the tasks finish in, so a seeded computation
gives the same list on either backend. Progress is reported per finished task
(nothing from inside a Ray task: more items than CPUs make a smoother bar). Ray gives
each task one CPU and sets OMP_NUM_THREADS=1 in it.
A `UserError` raised by `fn` on a worker reaches the caller as the same one-line
`UserError`, not a Ray traceback; the other tasks are then cancelled.
"""

from __future__ import annotations

import logging
import os
import socket
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

from laneprint.errors import SettingError, UserError
from laneprint.progress import ProgressFn, report

T = TypeVar("T")
R = TypeVar("R")

BACKENDS: tuple[str, ...] = ("local", "ray")
RAY_MISSING = "--backend ray needs Ray, which is not installed: pip install -e '.[ray]'"
CONNECT_TIMEOUT_S = 5.0  # [s] to reach --ray-address before giving up


def check_backend(backend: str, ray_address: str | None = None) -> None:
    """`UserError` for an unknown backend, an address without Ray, or Ray missing (before any work starts)."""
    if backend not in BACKENDS:
        raise UserError(f"unknown backend {backend!r}: choose one of {', '.join(BACKENDS)}")
    if ray_address and backend != "ray":
        raise SettingError("{0} joins a Ray cluster: add {1} ray", "ray_address", "backend")
    if backend == "ray":
        _import_ray()


def _import_ray() -> Any:
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")  # no usage-stats notice, no network call
    try:
        import ray
    except ImportError:
        raise UserError(RAY_MISSING) from None
    return ray


def _check_reachable(address: str) -> None:
    """`UserError` when nothing answers at HOST:PORT (Ray itself would retry for minutes)."""
    host, _, port = address.rpartition(":")
    if address == "auto" or "://" in address or not port.isdigit():
        return  # 'auto' and Ray Client addresses: Ray's own checks
    try:
        socket.create_connection((host.strip("[]") or "127.0.0.1", int(port)), timeout=CONNECT_TIMEOUT_S).close()
    except OSError as exc:
        raise UserError(
            f"cannot join the Ray cluster at {address}: {exc.strerror or exc} (is `ray start --head` running there?)"
        ) from None


def _start_ray(ray: Any, ray_address: str | None, num_cpus: int | None) -> None:
    quiet = {
        "logging_level": logging.ERROR,
        "log_to_driver": False,
    }  # a worker's failure still comes back as its exception
    try:
        if ray_address:
            _check_reachable(ray_address)
            ray.init(address=ray_address, **quiet)
        else:
            ray.init(num_cpus=num_cpus or os.cpu_count() or 1, include_dashboard=False, **quiet)
    except (ConnectionError, RuntimeError, ValueError, TimeoutError) as exc:
        if not ray_address:
            raise UserError(f"cannot start a local Ray instance: {_line(exc)}") from None
        auth = (
            ""
            if os.environ.get("RAY_AUTH_MODE")
            else (" (a cluster started with `ray start` asks for its token: set RAY_AUTH_MODE=token)")
        )
        raise UserError(f"cannot join the Ray cluster at {ray_address}: {_line(exc)}{auth}") from None


@contextmanager
def backend_session(
    backend: str = "local", ray_address: str | None = None, num_cpus: int | None = None
) -> Iterator[None]:
    """Keep one Ray instance up across several `run_tasks` calls (a no-op for ``local``).

    Joins `ray_address` or starts a local instance when Ray is not running yet, and
    shuts down on exit only what it started.
    """
    check_backend(backend, ray_address)
    if backend != "ray":
        yield
        return
    ray = _import_ray()
    if ray.is_initialized():
        yield
        return
    _start_ray(ray, ray_address, num_cpus)
    try:
        yield
    finally:
        ray.shutdown()


def run_tasks(
    fn: Callable[[T], R],
    items: Iterable[T],
    *,
    backend: str = "local",
    ray_address: str | None = None,
    num_cpus: int | None = None,
    progress: ProgressFn | None = None,
    label: str = "",
) -> list[R]:
    """``[fn(item) for item in items]`` on `backend`, in item order, reporting each finished task.

    :param fn: a module-level function of one item (run on Ray's workers with ``ray``)
    :param items: its inputs, picklable
    :param backend: ``local`` (this process, one after another) or ``ray``
    :param ray_address: a Ray cluster to join (``ray`` only); default: a local Ray instance
    :param num_cpus: CPUs of a local Ray instance (default: this machine's cores)
    :param progress: called as ``progress(done, total, label)`` when a task finishes
    :param label: the progress message
    :raises UserError: as raised by `fn`, one line; or for a bad backend / Ray missing
    """
    items = list(items)
    if not items:
        check_backend(backend, ray_address)
        return []  # no Ray instance started for nothing
    return list(
        iter_tasks(
            fn,
            items,
            backend=backend,
            ray_address=ray_address,
            num_cpus=num_cpus,
            progress=progress,
            label=label,
            total=len(items),
        )
    )


def iter_tasks(
    fn: Callable[[T], R],
    items: Iterable[T],
    *,
    backend: str = "local",
    ray_address: str | None = None,
    num_cpus: int | None = None,
    progress: ProgressFn | None = None,
    label: str = "",
    total: int | None = None,
    in_flight: int | None = None,
) -> Iterator[R]:
    """`run_tasks` as a stream: results in item order, each as soon as it and those before it are done.

    Items are taken from `items` lazily and at most `in_flight` tasks (default: twice
    the cluster's CPUs) are submitted or held unyielded at once, so a long stream of
    large items (file bytes) never sits in memory whole. `total` is the progress bar's
    length when `items` has no ``len``.
    """
    check_backend(backend, ray_address)
    if total is None and hasattr(items, "__len__"):
        total = len(items)  # type: ignore[arg-type]
    total = total or 0
    report(progress, 0, total, label)
    if backend == "local":
        for done, item in enumerate(items, 1):
            result = fn(item)
            report(progress, done, total, label)
            yield result
        return
    with backend_session(backend, ray_address, num_cpus):
        yield from _ray_stream(fn, items, progress, label, total, in_flight)


def _ray_stream(
    fn: Callable[[T], R], items: Iterable[T], progress: ProgressFn | None, label: str, total: int, in_flight: int | None
) -> Iterator[R]:
    import ray

    limit = in_flight or max(2, 2 * int(ray.cluster_resources().get("CPU", 1)))
    task = ray.remote(num_cpus=1)(fn)
    source = iter(enumerate(items))
    pending: dict[Any, int] = {}  # submitted, unfinished -> item index
    finished: dict[int, Any] = {}  # finished, not yet yielded (waiting for an earlier one)
    next_out, done = 0, 0
    try:
        while True:
            while len(pending) + len(finished) < limit:
                nxt = next(source, None)
                if nxt is None:
                    break
                pending[task.remote(nxt[1])] = nxt[0]
            if not pending:
                break
            ready, _ = ray.wait(list(pending), num_returns=1)
            for ref in ready:
                i = pending.pop(ref)
                finished[i] = _get(ray, ref)
                done += 1
                report(progress, done, total, label)
            while next_out in finished:
                yield finished.pop(next_out)
                next_out += 1
    finally:
        for ref in pending:  # an error or an abandoned stream: stop what is still queued
            ray.cancel(ref)


def _get(ray: Any, ref: Any) -> Any:
    """`ray.get` with a worker's `UserError`, and failures of the cluster itself, turned into one line.

    Any other exception raised by the task (a bug) keeps Ray's traceback of the worker.
    """
    try:
        return ray.get(ref)
    except ray.exceptions.RayTaskError as exc:
        cause = getattr(exc, "cause", None)
        if isinstance(cause, UserError):
            raise UserError(str(cause)) from None
        if isinstance(cause, ModuleNotFoundError):
            raise UserError(
                f"a Ray worker cannot import {cause.name!r}: install laneprint (the same version) "
                "on every machine of the cluster"
            ) from None
        raise
    except ray.exceptions.RayError as exc:  # a worker or node died, out of memory, ...
        raise UserError(f"a Ray task failed: {_line(exc)}") from None


def _line(exc: BaseException) -> str:
    """The first line of an exception's message (its type when it has none)."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__
