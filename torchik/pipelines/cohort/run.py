"""A cohort on Dask: batches as tasks on a local cluster or any cluster by address, each batch's
trials written by the worker as it finishes, the summary rebuilt from what is on disk.

Resuming: a trial whose folder holds a result with the fingerprint of its current spec (options,
input files' sizes and times) is finished and skipped; only the others are planned. A run that
stops (Ctrl-C, a lost client, a crash) keeps every trial written so far, and the same command
finishes the rest. Failed trials are finished too unless `retry_failed`.

Workers that die: Dask runs a dead worker's tasks again elsewhere (up to its
`distributed.scheduler.allowed-failures`); the trials the batch had already written are kept and
not tracked again. A batch that still fails (its workers keep dying) is split and each trial
submitted alone, so only a trial that kills every worker it runs on is recorded as failed.

With `scheduler`, the workers must see the manifest's files and `out` at the same paths (a shared
filesystem) and have torchik installed. One run at a time per `out`: a run starts by removing the
half-written folders that workers which died left there.
"""

from __future__ import annotations

import logging
import os
import shutil
import signal
import threading
import time
import uuid
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

from ...errors import InputError, optional
from .manifest import TrialSpec, read_manifest
from .plan import Batch, batch_size_for, plan_batches
from .summary import write_summary
from .trial import load_result, track_batch, write_failure

EXIT_ONCE_ENV = "TORCHIK_COHORT_EXIT_ONCE"  # tests: "TRIAL:MARKER", a worker dies once before writing TRIAL


@dataclass(frozen=True)
class CohortRun:
    """What a run did: trials in the manifest, skipped as finished before, tracked now (ok or
    failed), the batch sizes, the workers, the seconds from the first task to the last result
    (`seconds`) and to start the cluster and import torchik on its workers (`startup_s`), and the
    summary rows."""

    trials: int
    skipped: int
    tracked: int
    failed: int
    batch_sizes: tuple[int, ...]
    workers: int
    seconds: float
    startup_s: float
    rows: list[dict]

    @property
    def trials_per_minute(self) -> float:
        return 60.0 * self.tracked / self.seconds if self.seconds > 0 else float("nan")


def run_cohort(manifest: str | Path | list[TrialSpec], out: str | Path, *, client=None, scheduler: str | None = None,
               workers: int | None = None, batch_size: int | None = None, rrd: bool = False,
               retry_failed: bool = False, progress: bool = False,
               on_batch: Callable[[list[dict]], None] | None = None) -> CohortRun:
    """Track every unfinished trial of `manifest` (a file or its specs) into `out`, then write
    `out/summary.csv` and `out/summary.parquet`, also when interrupted.

    client: a distributed.Client to use (default: one on `scheduler`, an address, or else on a
    LocalCluster of `workers` single-threaded processes, default one per core).
    batch_size: trials per batch at most (default `batch_size_for`). on_batch(rows): called on
    the client after each batch. KeyboardInterrupt stops it: pending batches are cancelled and it
    is raised again once the summary is written."""
    specs = read_manifest(manifest) if isinstance(manifest, (str, Path)) else list(manifest)
    if batch_size is not None and batch_size < 1:
        raise InputError(f"the batch size must be positive, got {batch_size}")
    out = Path(out)
    (out / "trials").mkdir(parents=True, exist_ok=True)
    for stale in (out / "trials").glob(".*.part*"):  # folders of a worker that died while writing
        shutil.rmtree(stale, ignore_errors=True)
    fingerprints = [spec.fingerprint() for spec in specs]
    todo = [(s, f) for s, f in zip(specs, fingerprints) if not _finished(out, s, f, retry_failed)]
    run, n_workers, seconds, startup = uuid.uuid4().hex, 0, 0.0, 0.0
    sizes: tuple[int, ...] = ()
    try:
        if todo:
            start = time.perf_counter()
            with dask_client(client, scheduler, workers) as (dask, n_workers):
                startup = time.perf_counter() - start
                batches = plan_batches([s for s, _ in todo], [f for _, f in todo],
                                       batch_size or batch_size_for(len(todo), n_workers))
                sizes = tuple(len(b) for b in batches)
                start = time.perf_counter()
                _execute(dask, batches, out, run, rrd, len(specs) - len(todo), len(specs), progress, on_batch)
                seconds = time.perf_counter() - start
    finally:  # interrupted too: the summary then lists what finished
        rows = write_summary(out, specs, fingerprints)
    mine = [load_result(out, s.trial) for s, _ in todo]
    failed = sum(1 for r in mine if r and r.get("run") == run and r["row"]["status"] != "ok")
    return CohortRun(len(specs), len(specs) - len(todo), len(todo), failed, sizes, n_workers, seconds, startup, rows)


def _finished(out: Path, spec: TrialSpec, fingerprint: str, retry_failed: bool) -> bool:
    stored = load_result(out, spec.trial)
    return (stored is not None and stored.get("fingerprint") == fingerprint
            and (stored["row"]["status"] == "ok" or not retry_failed))


@contextmanager
def dask_client(client=None, scheduler: str | None = None, workers: int | None = None):
    """(client, its worker threads) on: `client` as it is; a cluster by address; or a new
    LocalCluster of `workers` single-threaded worker processes (default: one per usable core),
    closed on exit."""
    if client is not None:
        yield client, max(1, sum(client.nthreads().values()))
        return
    optional("distributed", "cohort", "torchik cohort")
    from distributed import Client, LocalCluster

    if scheduler:
        try:
            remote = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as exc:
            raise InputError(f"no Dask scheduler answers at {scheduler}: {exc}") from None
        with remote:
            yield remote, max(1, sum(remote.nthreads().values()))
        return
    import dask

    n = workers or len(os.sched_getaffinity(0))
    with ExitStack() as stack:
        if start_forkserver():
            stack.enter_context(dask.config.set({"distributed.worker.multiprocessing-method": "forkserver"}))
        with interrupts_deferred():  # distributed's start-up does not stop cleanly half-way
            # processes, one thread each: a step is hundreds of small torch calls that hold the GIL
            cluster = stack.enter_context(LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                                       dashboard_address=":0", silence_logs=logging.ERROR))
            local = stack.enter_context(Client(cluster))
            local.run(_import_torchik)  # counted as start-up, not tracking
        yield local, n


@contextmanager
def interrupts_deferred():
    """A Ctrl-C during the block is held and raised when it ends (then the cluster it started
    closes in order)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pressed = []
    handler = signal.signal(signal.SIGINT, lambda *_: pressed.append(True))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, handler)
    if pressed:
        raise KeyboardInterrupt


def start_forkserver() -> bool:
    """Start multiprocessing's fork server (what the local workers are then forked from) with
    torchik imported and SIGINT ignored; False where there is none (Windows: Dask spawns). Every
    worker, also one restarted after a crash, inherits both: it starts without importing torch
    again, and a Ctrl-C at the terminal (which signals the whole process group) stops this client,
    which then closes the cluster, instead of killing workers half-way. A Ctrl-C during the fork
    server's own start (milliseconds) is lost."""
    import multiprocessing
    from multiprocessing import forkserver

    if "forkserver" not in multiprocessing.get_all_start_methods():
        return False
    # the URDF parser is loaded on first use (urdf.urdf_class, a quick import): not pytorch_kinematics, whose
    # package would bring its IK solvers and matplotlib into every worker
    preload = ["distributed", "torchik.pipelines.cohort.trial"]
    multiprocessing.get_context("forkserver").set_forkserver_preload(preload)
    main = threading.current_thread() is threading.main_thread()
    handler = signal.signal(signal.SIGINT, signal.SIG_IGN) if main else None
    try:
        forkserver.ensure_running()
    finally:
        if main:
            signal.signal(signal.SIGINT, handler)
    return True


def _import_torchik() -> None:
    import torchik.pipelines.cohort.trial  # noqa: F401
    from torchik.method.kinematics.urdf import urdf_class

    urdf_class()


def _execute(client, batches: list[Batch], out: Path, run: str, rrd: bool, done: int, total: int, progress: bool,
             on_batch) -> None:
    """Submit the batches, follow them as they complete; a batch that raises (its workers died
    too often) is submitted again one trial per task; a single trial that raises is recorded failed."""
    from distributed import as_completed
    from tqdm import tqdm

    exit_once = tuple(os.environ[EXIT_ONCE_ENV].split(":", 1)) if os.environ.get(EXIT_ONCE_ENV) else None

    def submit(batch: Batch, name: str):
        return client.submit(track_batch, batch, str(out), run, rrd, exit_once, key=f"cohort-{name}-{run[:12]}")

    futures = {submit(b, str(b.index)): b for b in batches}
    pending = as_completed(list(futures))
    bar = tqdm(total=total, initial=done, unit="trial", desc="cohort", disable=not progress, delay=1.0)
    try:
        for future in pending:
            batch = futures.pop(future)
            try:
                rows = future.result()
            except Exception as exc:
                if len(batch) > 1:
                    for i, item in enumerate(zip(batch.trials, batch.fingerprints, batch.frames)):
                        single = replace(batch, trials=item[:1], fingerprints=item[1:2], frames=item[2:])
                        again = submit(single, f"{batch.index}.{i}")
                        futures[again] = single
                        pending.add(again)
                    continue
                # KilledWorker: every worker it ran on died
                rows = [write_failure(out, batch.trials[0], batch.fingerprints[0], run,
                                      f"its task failed: {type(exc).__name__}: {exc}")]
            future.release()
            bar.update(len(batch))
            if on_batch is not None:
                on_batch(rows)
    except BaseException:  # Ctrl-C or a lost scheduler: start nothing more; what finished is on disk
        client.cancel(list(futures))
        raise
    finally:
        bar.close()
