"""Where many independent runs go: local processes, or a Ray cluster (``maptidal batch`` and ``sweep``).

:func:`run_jobs` calls ``function(item)`` for every item and yields ``(index, result)`` as each run
finishes, whatever the executor. A run is a pure function of its item (missions and sweep cells seed
everything they draw from the item), so the same items give the same results locally and on Ray.

- ``local`` with one job runs in this process; with more, in a pool of fresh (spawned) processes (at
  most one per run and per CPU: :func:`usable_jobs`), so no GL context or thread is inherited from the
  parent.
- ``ray`` sends the runs to a Ray cluster: ``ray.init(address=...)`` with ``ray_address``, or a local
  Ray instance with ``jobs`` CPUs when no address is given. Every node must have maptidal installed (the
  functions travel by reference, as importable names). Ray is an optional extra (``pip install -e .[ray]``).

An optional ``initializer(*initargs)`` runs once in each worker process before its first run (the sweep
uses it to build its keyframes and coverage model once per process rather than once per cell).

Ctrl-C and SIGTERM are the parent's to handle. Local workers start with both held (:func:`signals_held`:
a Ctrl-C at a terminal reaches the whole process group, and a spawned child that it catches while it
reads its start-up data dies with a traceback of its own), then ignore SIGINT and take SIGTERM again
(:func:`release_in_child`); when the parent is interrupted it terminates the runs under way rather than
waiting for them, which for a batch of missions could take minutes.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import uuid
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from contextlib import contextmanager
from typing import Any

EXECUTORS = ("local", "ray")
# the worker processes render headless, as the parent does (README, "Two commands")
WORKER_ENVIRONMENT = ("MUJOCO_GL", "PYOPENGL_PLATFORM")

_initialised: set[str] = set()  # the initializer tokens already run in this (worker) process
# SIGALRM too: maptidal.cli.interrupts raises a Ctrl-C that came during an import on a timer
HELD_SIGNALS = {signal.SIGINT, signal.SIGTERM, signal.SIGALRM}


@contextmanager
def signals_held() -> Iterator[None]:
    """Hold (block) SIGINT, SIGTERM and SIGALRM in this thread while child processes start; one that came
    meanwhile is delivered when the block ends. The children inherit the block: they call
    :func:`release_in_child` once they are running."""
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, HELD_SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def release_in_child() -> None:
    """In a child started under :func:`signals_held`: ignore SIGINT (Ctrl-C reaches the whole process
    group, and it is the parent's to handle), and let SIGTERM end the child again."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, HELD_SIGNALS)


def usable_jobs(jobs: int, runs: int) -> int:
    """Local processes worth starting for ``runs`` runs: at most one per run and one per CPU."""
    return max(1, min(jobs, runs, os.cpu_count() or 1))


def _local_worker_setup(initializer: Callable | None, initargs: tuple) -> None:
    release_in_child()
    if initializer is not None:
        initializer(*initargs)


def _call_once_initialised(token: str, initializer: Callable | None, initargs: tuple, function, item):
    """A Ray task: run the initializer the first time this worker process sees ``token``, then the run."""
    if initializer is not None and token not in _initialised:
        initializer(*initargs)
        _initialised.add(token)
    return function(item)


def run_jobs(
    function: Callable[[Any], Any],
    items: Iterable[Any],
    executor: str = "local",
    jobs: int = 1,
    ray_address: str | None = None,
    initializer: Callable | None = None,
    initargs: tuple = (),
) -> Iterator[tuple[int, Any]]:
    """Run ``function`` on every item; yield ``(index, result)`` as runs finish (module docstring).

    A run that raises re-raises here, and the runs not yet started are cancelled."""
    if executor not in EXECUTORS:
        raise ValueError(f"unknown executor {executor!r}; known: {', '.join(EXECUTORS)}")
    if jobs < 1:
        raise ValueError(f"jobs must be at least 1, got {jobs}")
    if ray_address is not None and executor != "ray":
        raise ValueError("a Ray address needs --executor ray")
    items = list(items)
    if executor == "ray":
        yield from _run_on_ray(function, items, jobs, ray_address, initializer, initargs)
        return
    jobs = usable_jobs(jobs, len(items))
    if jobs == 1:
        if initializer is not None:
            initializer(*initargs)
        for index, item in enumerate(items):
            yield index, function(item)
    else:
        yield from _run_in_processes(function, items, jobs, initializer, initargs)


def _run_in_processes(function, items, jobs, initializer, initargs) -> Iterator[tuple[int, Any]]:
    pool = ProcessPoolExecutor(
        max_workers=jobs,
        mp_context=multiprocessing.get_context("spawn"),
        initializer=_local_worker_setup,
        initargs=(initializer, initargs),
    )
    try:
        with signals_held():  # the workers are spawned as the runs are submitted
            futures = {pool.submit(function, item): index for index, item in enumerate(items)}
        pending = set(futures)
        while pending:
            finished, pending = wait(pending, return_when=FIRST_COMPLETED)
            for future in sorted(finished, key=futures.get):
                yield futures[future], future.result()
    except BaseException:
        # interrupted, or the caller stopped early: end the runs under way rather than wait for them
        # (ProcessPoolExecutor has no public way to; its _processes maps pids to the workers)
        for process in list((pool._processes or {}).values()):
            process.terminate()
        raise
    finally:
        pool.shutdown(cancel_futures=True)


def _run_on_ray(function, items, jobs, address, initializer, initargs) -> Iterator[tuple[int, Any]]:
    try:
        import ray
    except ImportError:
        raise ValueError("--executor ray needs Ray: pip install -e .[ray]") from None
    started_here = not ray.is_initialized()
    if started_here:
        environment = {name: os.environ[name] for name in WORKER_ENVIRONMENT if name in os.environ}
        options: dict[str, Any] = {
            "runtime_env": {"env_vars": environment},
            "log_to_driver": False,
            "include_dashboard": False,
        }
        if address is None:
            options["num_cpus"] = jobs  # a local instance of this size, gone when the runs are
        ray.init(address=address, **options)
    try:
        remote = ray.remote(num_cpus=1, max_retries=0)(_call_once_initialised)
        token = uuid.uuid4().hex
        references = {
            remote.remote(token, initializer, initargs, function, item): index
            for index, item in enumerate(items)
        }
        pending = list(references)
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            try:
                result = ray.get(ready[0])
            except ray.exceptions.RayTaskError as err:
                for reference in pending:
                    ray.cancel(reference)
                raise err.as_instanceof_cause() from None
            yield references[ready[0]], result
    finally:
        if started_here:
            ray.shutdown()
