"""Where the runs go: the local process pool (default, no extra install) or a Dask cluster.

    results = run_all(specs, Engine("local", workers=2))
    results = run_all(specs, Engine("dask"))                                   # a local cluster
    results = run_all(specs, Engine("dask", cluster="tcp://10.0.0.5:8786"))    # a running one
    results = run_all(specs, Engine("ray", cluster="ray://10.0.0.5:10001"))

Each engine maps :func:`fcmpc.montecarlo.runs.run_specs` over batches of ``(index, RunSpec)`` and
yields ``(index, RunOutput)`` as batches finish, in completion order, so a caller can store
results as they arrive (a sweep resumes from them). Runs are pure functions of their spec, so
every engine gives the same numbers bit for bit.

Dask (``pip install -e '.[cluster]'``) is the primary distributed engine: its
``distributed.LocalCluster`` is a few pure-Python processes started in seconds, which suits a
2-core box as well as a cluster reached by address (``dask scheduler`` + ``dask worker`` on the
machines, each with this package installed). Ray works the same way (``pip install ray``) and
is not installed by any extra. Workers need the same package versions as the client; numpy's
BLAS threads are pinned to one per worker, since the matrices are 2x2 to 15x15: by environment
for the engines that start fresh processes (Dask, Ray), by threadpoolctl in the local pool's
forked workers, which inherit the BLAS the parent has already loaded (a library caller whose
numpy runs two threads per core made a 50 x 3 Monte Carlo take 23.5 s instead of 11.7 s).
"""
from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass

from threadpoolctl import threadpool_limits

from companion.cli import UsageError
from fcmpc.montecarlo.runs import RunOutput, RunSpec, run_specs

__all__ = ["BATCH_CAP", "ENGINES", "Engine", "batches", "local_pool", "one_blas_thread", "run_all"]

ENGINES = ("local", "dask", "ray")
_ONE_THREAD = {var: "1" for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}


@dataclass(frozen=True)
class Engine:
    """``kind``: local, dask or ray; ``workers``: processes (local pool, or a local cluster's
    workers; None: one per core); ``cluster``: address of a running scheduler (dask
    ``tcp://HOST:8786``, ray ``ray://HOST:10001``), None to start a local one."""

    kind: str = "local"
    workers: int | None = None
    cluster: str | None = None

    @property
    def worker_count(self) -> int:
        return self.workers or os.cpu_count() or 1


BATCH_CAP = 32          # most runs in one task: results still arrive (and are stored) steadily
GUIDED_SHARE = 2        # a task takes 1 / (GUIDED_SHARE x workers) of the runs still to hand out


def batches(items: list[tuple[int, RunSpec]], workers: int) -> list[list]:
    """Split the tasks into batches, guided as OpenMP's schedule is: each takes a share of the
    runs still left (at most :data:`BATCH_CAP`), so they shrink to one run per task at the end
    and no worker is left finishing a whole batch while the others idle. Big batches first,
    because the runs of a batch fly side by side (:func:`fcmpc.montecarlo.inprocess.fly_batch`) and share the
    per-step overhead: here a run costs 0.26 s alone, 0.16 s in a batch of 9, 0.15 s in one of 30;
    fixed batches of 9 with a tail of 24 single runs made a 50 x 3 Monte Carlo on 2 workers about
    1 s slower (14.9 against 13.5 s, medians of three)."""
    split, start, count, share = [], 0, len(items), GUIDED_SHARE * max(1, workers)
    while start < count:
        left = count - start
        size = 1 if left <= max(1, workers) else max(1, min(BATCH_CAP, left // share))
        split.append(items[start:start + size])
        start += size
    return split


def run_all(specs: Iterable[tuple[int, RunSpec]], engine: Engine, task: Callable = run_specs,
            batched: bool = True) -> Iterator[tuple[int, RunOutput]]:
    """Yield ``(index, RunOutput)`` for every ``(index, spec)`` as runs finish. ``task`` maps a list
    of ``(index, spec)`` to a list of ``(index, RunOutput)`` (default :func:`run_specs`, in-process);
    ``batched`` False hands each task one run (a run that is a mission of processes,
    :mod:`fcmpc.montecarlo.flown`, gains nothing from company)."""
    items = list(specs)
    if not items:
        return iter(())
    if engine.kind not in ENGINES:
        raise UsageError(f"--engine {engine.kind}: choose from {', '.join(ENGINES)}")
    split = (lambda workers: batches(items, workers)) if batched else (lambda workers: [[item] for item in items])
    if engine.kind == "dask":
        return _dask(split, engine, task)
    if engine.kind == "ray":
        return _ray(split, engine, task)
    if engine.cluster:
        raise UsageError("--cluster needs --engine dask or ray")
    return _local(items, engine.worker_count, split, task)


def one_blas_thread() -> None:
    """Pool initializer: one BLAS thread in this process, whenever numpy loaded its BLAS (the
    environment variables act only before that, and a forked worker inherits the parent's)."""
    threadpool_limits(1)


def local_pool(workers: int) -> ProcessPoolExecutor:
    """The local engine's pool: ``workers`` processes, one BLAS thread each."""
    os.environ.update({k: v for k, v in _ONE_THREAD.items() if k not in os.environ})
    return ProcessPoolExecutor(workers, initializer=one_blas_thread)


def _local(items: list, workers: int, split: Callable, task: Callable) -> Iterator[tuple[int, RunOutput]]:
    if workers <= 1:
        for index, spec in items:
            with threadpool_limits(1):   # for the run only: the caller's own numpy keeps its threads
                output = task([(index, spec)])[0][1]
            yield index, output
        return
    with local_pool(workers) as pool:
        futures = [pool.submit(task, batch) for batch in split(workers)]
        try:
            for future in as_completed(futures):
                yield from future.result()
        finally:
            for future in futures:
                future.cancel()


def _dask(split: Callable, engine: Engine, task: Callable) -> Iterator[tuple[int, RunOutput]]:
    try:
        from distributed import Client, LocalCluster
        from distributed import as_completed as dask_completed
    except ImportError:
        raise UsageError("--engine dask needs the cluster extra: pip install -e '.[cluster]'") from None
    cluster = None
    if engine.cluster:
        try:
            client = Client(engine.cluster, timeout="20s")
        except OSError as err:
            raise UsageError(f"--cluster {engine.cluster}: cannot connect ({err})") from None
    else:
        os.environ.update({k: v for k, v in _ONE_THREAD.items() if k not in os.environ})
        # on loopback: binding to the host's name waits on name resolution (minutes without DNS)
        cluster = LocalCluster(n_workers=engine.worker_count, threads_per_worker=1, processes=True,
                               host="127.0.0.1", dashboard_address=None, silence_logs=40)
        client = Client(cluster)
    try:
        workers = max(1, len(client.scheduler_info().get("workers", {})) or engine.worker_count)
        futures = client.map(task, split(workers), pure=False)
        for future in dask_completed(futures):
            yield from future.result()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _ray(split: Callable, engine: Engine, task: Callable) -> Iterator[tuple[int, RunOutput]]:
    try:
        import ray
    except ImportError:
        raise UsageError("--engine ray needs ray: pip install ray") from None
    ray.init(address=engine.cluster, num_cpus=None if engine.cluster else engine.worker_count,
             runtime_env={"env_vars": _ONE_THREAD}, include_dashboard=False, ignore_reinit_error=True,
             log_to_driver=False)
    try:
        remote = ray.remote(num_cpus=1)(task)
        pending = [remote.remote(batch) for batch in split(engine.worker_count)]
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            yield from ray.get(done[0])
    finally:
        ray.shutdown()
