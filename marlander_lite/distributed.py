"""Run independent jobs in processes on this machine or as tasks on a Ray cluster.

Training seeds (``marlander sweep``) and blocks of evaluation trials (``marlander reproduce``) are
independent jobs: a function applied to a list of picklable arguments. :func:`map_jobs` runs them

- ``backend="local"``: in a pool of worker processes on this machine (``workers`` at a time), or
- ``backend="ray"``: as Ray tasks (https://docs.ray.io). ``address=None`` starts a private Ray
  instance on this machine; ``"auto"`` joins the cluster this machine belongs to (after
  ``ray start --head`` here, or ``ray start --address HEAD:6379`` on a worker); ``"HOST:PORT"``
  joins the cluster whose head listens there.

Either way the results come back in the order the jobs finish, so a caller can save each one as soon
as it arrives. A job's exception is returned, not raised, so that one failed seed does not lose the
others. Ray is an optional dependency (``pip install marlander_lite[ray]``), imported only here and
only when asked for.
"""

from __future__ import annotations

import multiprocessing
import socket
from collections.abc import Callable, Iterator, Sequence
from concurrent import futures
from typing import Any, Literal, TypeVar, get_args

Backend = Literal["local", "ray"]
BACKENDS: tuple[str, ...] = get_args(Backend)

CONNECT_TIMEOUT_S = 5.0
"""How long to wait for a Ray head's port to answer before giving up with a clear error (s)."""

Job = TypeVar("Job")


def check_backend(backend: str) -> None:
    """Raise ``ValueError`` unless ``backend`` is one of :data:`BACKENDS`."""
    if backend not in BACKENDS:
        raise ValueError(f"Unknown backend {backend!r}; allowed: {', '.join(BACKENDS)}.")


def map_jobs(
    function: Callable[[Job], Any],
    jobs: Sequence[Job],
    *,
    backend: Backend = "local",
    workers: int = 1,
    address: str | None = None,
    cpus_per_job: int = 1,
) -> Iterator[tuple[Job, Any]]:
    """Yield ``(job, function(job))`` as each job finishes; a job that raised yields its exception.

    Args:
        function: a module-level function (it is pickled to the workers).
        jobs: its arguments, one per job.
        backend: ``local`` (processes on this machine) or ``ray``.
        workers: local backend: processes at a time (1: run in this process, one after another).
        address: ray backend: ``None`` (a private instance here), ``auto`` or ``HOST:PORT``.
        cpus_per_job: ray backend: CPUs Ray reserves for each job (e.g. a run's torch threads).
    """
    check_backend(backend)
    if backend == "ray":
        yield from _map_ray(function, jobs, address, cpus_per_job)
    elif workers <= 1 or len(jobs) <= 1:
        for job in jobs:
            yield job, _call(function, job)
    else:
        # fork starts workers without re-importing torch and friends; elsewhere fall back to spawn.
        method = "fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn"
        context = multiprocessing.get_context(method)
        with futures.ProcessPoolExecutor(min(workers, len(jobs)), mp_context=context) as pool:
            pending = {pool.submit(function, job): job for job in jobs}
            for done in futures.as_completed(pending):
                error = done.exception()
                yield pending[done], error if error is not None else done.result()


def _call(function: Callable[[Job], Any], job: Job) -> Any:
    try:
        return function(job)
    except Exception as error:  # returned, like a worker's, so that one failure does not stop the others
        return error


def connect_ray(address: str | None, num_cpus: int | None = None) -> None:
    """Start or join a Ray cluster; an address nobody answers at fails within seconds.

    ``ray.init`` itself keeps retrying an unreachable head for a long time, so a ``HOST:PORT`` is
    first probed with a plain TCP connection (:data:`CONNECT_TIMEOUT_S`), even when Ray is already running here.
    """
    try:
        import ray
    except ModuleNotFoundError:
        raise ValueError(
            "--backend ray needs Ray: pip install 'marlander_lite[ray]' (environment.lock pins it)."
        ) from None
    if address not in (None, "auto"):
        host, _, port = address.rpartition(":")
        if not host or not port.isdigit():
            raise ValueError(f"--address {address!r}: expected HOST:PORT (e.g. 10.0.0.5:6379) or 'auto'.")
        try:
            socket.create_connection((host, int(port)), timeout=CONNECT_TIMEOUT_S).close()
        except OSError as error:
            raise ValueError(
                f"--address {address}: no Ray head answers there ({error}). Start one with "
                f"'ray start --head --port {port}' on {host}, or check the address."
            ) from None
    if ray.is_initialized():  # e.g. a notebook or test that started Ray itself: use that instance
        return
    try:
        if address is None:
            ray.init(num_cpus=num_cpus, include_dashboard=False, log_to_driver=False)
        else:
            ray.init(address=address, log_to_driver=False)
    except ConnectionError as error:
        raise ValueError(f"--address {address}: could not join a Ray cluster ({error}).") from None


def _map_ray(
    function: Callable[[Job], Any], jobs: Sequence[Job], address: str | None, cpus_per_job: int
) -> Iterator[tuple[Job, Any]]:
    import ray

    connect_ray(address)
    remote = ray.remote(num_cpus=cpus_per_job, max_retries=0)(function)
    pending = {remote.remote(job): job for job in jobs}
    while pending:
        (done,), _ = ray.wait(list(pending), num_returns=1)
        job = pending.pop(done)
        try:
            yield job, ray.get(done)
        except ray.exceptions.RayTaskError as error:
            cause = error.as_instanceof_cause()
            yield job, cause if isinstance(cause, Exception) else RuntimeError(str(error))
