"""Independent trainings side by side: worker processes with one torch thread each.

A leave-objects-out evaluation trains many small detectors that do not depend on each other (every
fold's detector and its inner folds' detectors). Small convolutions use a second thread poorly
(thread wake-ups cost as much as the work), so on a machine with ``W`` cores ``W`` processes of one
thread each finish such a set of jobs about ``W`` times sooner than one process of ``W`` threads.
This is not data parallelism: each job is one whole, seeded, single-thread training, so its result
does not depend on how many workers ran beside it (one training spread over processes is torchrun
DDP's job, :mod:`slipsense.training.distributed`).

The pool is :class:`concurrent.futures.ProcessPoolExecutor` with forked workers on Linux (the data
every job reads is inherited, not copied; jobs name what they need of it) and spawned ones
elsewhere (the data is then sent to each worker once).

Workers end with the process that started them, whatever ended it: a worker asks the kernel for
SIGKILL when its parent dies (Linux's ``PR_SET_PDEATHSIG``) and, everywhere, watches for a new parent
(a killed parent's children are handed to another). Workers ignore SIGINT, so a Ctrl-C at the
terminal reaches the parent alone, which ends them and stops with one line (the command line's).
"""

from __future__ import annotations

import contextlib
import ctypes
import gc
import multiprocessing
import os
import queue as queue_mod
import signal
import sys
import threading
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from typing import Any, Callable, Sequence

import cv2
from tqdm import tqdm

_SHARED: Any = None
_TICKS: Any = None


def default_workers(jobs: int) -> int:
    """One worker per core this process may run on (its affinity mask where the OS has one), no more
    than there are jobs."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(cores, jobs))


def end_with_parent(parent: int) -> None:
    """Make this worker process end when ``parent`` (the pid that started it) ends, and leave Ctrl-C
    to the parent. Called first thing in every worker (pool workers here, data loader workers).

    A worker blocked on its job queue would otherwise outlive a parent killed with SIGKILL (which no
    handler of the parent sees), asleep and holding its memory, reparented to init.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent ends its workers itself on Ctrl-C
    if hasattr(signal, "pthread_sigmask"):  # blocked by the parent while it forked: see _sigint_held
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    if sys.platform == "linux":
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL, 0, 0, 0)  # 1: PR_SET_PDEATHSIG
    if os.getppid() != parent:  # the parent died before the request above took effect
        os._exit(1)
    threading.Thread(target=_watch_parent, args=(parent,), daemon=True, name="slipsense-parent-watch").start()


def _watch_parent(parent: int, every_s: float = 0.5) -> None:
    """Where the platform has no parent-death signal: a dead parent's children get a new parent."""
    while os.getppid() == parent:
        time.sleep(every_s)
    os._exit(1)


def _init_worker(shared: Any, ticks: Any, parent: int) -> None:
    global _SHARED, _TICKS
    end_with_parent(parent)
    os.environ["OMP_NUM_THREADS"] = "1"  # before torch starts its thread pool, if a job imports it
    _SHARED, _TICKS = shared, ticks


@contextlib.contextmanager
def _ready_to_fork():
    """While workers are forked: this process's garbage collected and what is left frozen (a forked
    worker that collected a cycle holding an ONNX Runtime session, a live detector's garbage by then,
    would wait forever in its destructor for threads that do not exist after a fork), and OpenCV on
    one thread (a forked child that finds OpenCV's thread pool, whose threads stay behind in the
    parent, hangs in it; with no pool there is nothing to find). Both are undone afterwards."""
    gc.collect()
    gc.freeze()  # objects from before the fork: never collected in a worker (nor copied on write)
    before = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        yield
    finally:
        cv2.setNumThreads(before)
        gc.unfreeze()


@contextlib.contextmanager
def _sigint_held():
    """SIGINT blocked in this thread while it starts workers: a worker inherits the block and
    unblocks only once it ignores SIGINT (a Ctrl-C between its start and then would end it with a
    traceback). A Ctrl-C meanwhile stays pending here and is raised when the block ends."""
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    before = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, before)


def _in_worker(fn: Callable, index: int, job: Any) -> Any:
    if "torch" in sys.modules:  # imported with fn's module: one thread, whatever it read at import
        sys.modules["torch"].set_num_threads(1)
    return fn(_SHARED, job, lambda n: _TICKS.put((index, n)))


class _Progress:
    """The bar over all jobs (remaining time of the whole set) and, where jobs belong to groups
    (the trainings of one fold), the remaining time of the earliest unfinished group."""

    def __init__(self, weights: Sequence[float], groups: Sequence[str] | None, desc: str, show: bool):
        self.weights, self.groups = list(weights), list(groups) if groups is not None else None
        self.done = [0.0] * len(self.weights)
        self.t0 = time.perf_counter()
        self.bar = tqdm(total=sum(self.weights), desc=desc, unit="u") if show else None

    def tick(self, job: int, units: float) -> None:
        self.done[job] += units
        if self.bar is None:
            return
        self.bar.update(units)
        if self.groups is not None:
            rate = sum(self.done) / max(time.perf_counter() - self.t0, 1e-9)
            for g in dict.fromkeys(self.groups):
                left = sum(w - d for w, d, gg in zip(self.weights, self.done, self.groups) if gg == g)
                if left > 1e-9:
                    self.bar.set_postfix_str(f"{g}: ~{left / max(rate, 1e-9):.0f} s left", refresh=False)
                    break

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def run_jobs(
    fn: Callable[[Any, Any, Callable[[float], None]], Any],
    jobs: Sequence[Any],
    shared: Any,
    workers: int | None = None,
    weights: Sequence[float] | None = None,
    on_done: Callable[[int, Any], None] | None = None,
    progress: bool = True,
    desc: str = "training",
    groups: Sequence[str] | None = None,
    longest_first: bool = False,
) -> list[Any]:
    """Run ``fn(shared, job, tick)`` for every job; returns the results in job order.

    Args:
        fn: a module-level function (workers import it); ``tick(units)`` reports progress.
        jobs: small descriptions of the work; ``shared`` the data they read (sent once per worker).
        workers: processes (default :func:`default_workers`); 1 runs every job here, in order,
            with this process's threads.
        weights: progress units each job will tick in total (default 1 each), for the bar's
            remaining-time estimate. Jobs start in the order given: put the long ones first where
            results are not written as they come (where they are, finishing early matters more).
        on_done: called here with ``(job index, result)`` as each job finishes.
        groups: a label per job (e.g. its fold); the bar also shows the earliest unfinished
            group's remaining time.
        longest_first: start the jobs on worker processes by their weight, heaviest first (results
            still in job order): where only the last result counts, the last job to start is a short
            one (a detector's 4 trainings on 2 workers: 178 units of work on the busier worker, not 191).
    """
    n = len(jobs)
    weights = list(weights) if weights is not None else [1.0] * n
    workers = default_workers(n) if workers is None else max(1, min(int(workers), max(n, 1)))
    bar = _Progress(weights, groups, f"{desc} ({n} jobs, {workers} worker{'s' * (workers > 1)})", progress)
    results: list[Any] = [None] * n
    on_done = on_done or (lambda i, result: None)
    try:
        if workers == 1:
            for i, job in enumerate(jobs):
                results[i] = fn(shared, job, lambda u, i=i: bar.tick(i, u))
                on_done(i, results[i])
            return results
        # Forked workers on Linux: they start at once with ``shared`` already in memory (nothing is
        # pickled), and a user's script that calls slipsense.fit needs no ``if __name__ == "__main__"``
        # guard (a spawned worker imports the main script again). Elsewhere, spawned.
        fork = sys.platform == "linux" and "fork" in multiprocessing.get_all_start_methods()
        ctx = multiprocessing.get_context("fork" if fork else "spawn")
        ticks = ctx.Queue()
        init = (shared, ticks, os.getpid())
        with (
            _ready_to_fork(),
            ProcessPoolExecutor(workers, mp_context=ctx, initializer=_init_worker, initargs=init) as pool,
        ):
            try:
                with _sigint_held():  # the pool starts its workers at the first submit
                    order = sorted(range(n), key=lambda i: -weights[i]) if longest_first else range(n)
                    pending = {pool.submit(_in_worker, fn, i, jobs[i]): i for i in order}
                while pending:
                    done, _ = wait(pending, timeout=0.5, return_when=FIRST_COMPLETED)
                    _drain(ticks, bar)
                    for fut in done:
                        i = pending.pop(fut)
                        results[i] = fut.result()  # a worker's error is raised here
                        on_done(i, results[i])
            except BaseException:
                # the workers, taken before shutdown: it forgets them (``_processes = None``), and a
                # kill loop run after it found none, so a Ctrl-C waited for the jobs under way
                procs = list((getattr(pool, "_processes", None) or {}).values())
                manager = getattr(pool, "_executor_manager_thread", None)
                pool.shutdown(wait=False, cancel_futures=True)
                # kill the workers now (their jobs are not wanted): else leaving the pool waits for them
                for proc in procs:
                    if proc.is_alive():
                        proc.kill()
                _forget_manager(manager)
                raise
            time.sleep(0.05)
            _drain(ticks, bar)
        return results
    finally:
        bar.close()


def _forget_manager(manager: threading.Thread | None) -> None:
    """Let the pool's manager thread end (it sees its workers killed and closes its wake-up pipe), then
    drop it from the interpreter's exit hook: Python 3.11's hook would write to that closed pipe at exit
    and print a traceback after the command's one line."""
    if manager is None:
        return
    manager.join(timeout=2.0)
    if not manager.is_alive():
        from concurrent.futures import process

        getattr(process, "_threads_wakeups", {}).pop(manager, None)


def _drain(ticks: Any, bar: _Progress) -> None:
    while True:
        try:
            job, units = ticks.get_nowait()
        except queue_mod.Empty:
            return
        bar.tick(job, units)
