"""Frames in parallel: one per-frame function mapped over a series, in process or on Dask.

:func:`frame_map` runs ``func(item, context)`` for every item of a series (frame indices, or
small per-frame records) and hands back ``(item, result)`` pairs *as they complete*, so that
the caller records each frame (and, e.g., links it) as soon as it exists:

- ``Parallel(workers=1)`` (the default): in this process, in order, exactly as a plain loop;
  Dask is not even imported;
- ``Parallel(workers=N)``: on a :class:`distributed.LocalCluster` of ``N`` worker processes
  started for the call and stopped after it, each running one frame at a time with
  ``threads`` compute threads (default: the cores divided among the workers), its memory
  bounded by ``memory_limit`` (default: the machine's memory divided among them); no more
  workers than the available memory holds (:meth:`Parallel.capped`, with the map's
  :func:`memory_per_worker`), and, from a command line, than the machine has cores;
- ``Parallel(scheduler="tcp://host:port")``: on an existing cluster (``dask scheduler`` /
  ``dask worker``, or ``dask-jobqueue`` on a batch system); ``workers`` is then the cluster's.

Several maps in a row (the stages of a study) can share one local cluster instead of starting
one each: :func:`shared_cluster`.

Shared read-only inputs (a PSF bank, a projector) are a :class:`WorkerContext`: its
``build(*args)`` runs at most once per process — in this process for ``workers=1``, once in
every worker process otherwise — with ``args`` sent to each worker once (``scatter`` with
``broadcast``), never once per frame: it needs neither a cache nor a file system shared with
the workers (timings: docs/validation_notes.md, "Time").

Failures. A worker process that dies (killed, out of memory) has its frames redone on
another one by the scheduler (a finished frame whose result was lost with it, and which the
scheduler cancels instead, is submitted again, at most ``retries`` times, and the context's
arguments are sent again if every copy of them went with the dead workers); an unexpected
exception in a frame is retried ``retries`` times. An error the toolkit raises on purpose
(:class:`~hrvbase.errors.HrvError`, e.g. an unreadable frame) is not retried: the map stops
(frames not started are cancelled, those running finish), hands back every frame that
finished, then raises that error, as the serial loop would.

Messages. What a frame logs on a worker (the toolkit's loggers, at this process's levels) is
sent back with its result and logged here, as if the frame had run here.

Peak memory. When the map ends, the peak resident memory of every worker process (``ru_maxrss``)
is logged at info level and kept in :attr:`FrameMap.peak_memory_bytes`.
"""

from __future__ import annotations

import dataclasses
import logging
import signal
import sys
import threading
import time
import uuid
import warnings
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import CancelledError
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

from .errors import HrvError, InputError
from .scheduler import (
    CONNECT_TIMEOUT_S,
    SCHEDULER_SCHEMES,
    _open_client,
    check_scheduler,
    scheduler_address,
)
from .threads import available_cores

log = logging.getLogger(__name__)

#: Memory one local worker process needs besides its frames' shared context (bytes): Python
#: with Dask and the toolkit imported, and a small frame's arrays (docs/validation_notes.md,
#: "Time").
WORKER_BASE_BYTES = 256 * 2**20


@dataclass(frozen=True)
class Parallel:
    """How the frames of a series are spread over processes.

    Attributes
    ----------
    workers : int or "auto"
        Worker processes of a local cluster; ``1``: in this process, no Dask (the default);
        ``"auto"``: one per core. Ignored with ``scheduler``.
    scheduler : str or None
        Address of an existing Dask scheduler (``tcp://host:port``); the frames run on its
        workers.
    threads : int or None
        Compute threads of each worker process (Dr.Jit); default: the cores divided among the
        local workers (at least 1), or all of a remote worker's cores.
    memory_limit : str or None
        Memory bound of each local worker (Dask syntax: ``"4GiB"``, ``"auto"``: the machine's
        memory divided among the workers; None: unbounded). A worker above 95 % of it is
        restarted and its frame redone.
    retries : int
        Extra attempts of a frame whose worker died or that raised an unexpected exception.
    """

    workers: int | str = 1
    scheduler: str | None = None
    threads: int | None = None
    memory_limit: str | None = "auto"
    retries: int = 2

    def __post_init__(self) -> None:
        w = self.workers
        if w != "auto" and (isinstance(w, bool) or not isinstance(w, int) or w < 1):
            raise InputError(f"workers must be an integer >= 1 or 'auto', got {w!r}")
        if self.scheduler is not None:
            if not isinstance(self.scheduler, str) or not self.scheduler.strip():
                raise InputError(
                    f"scheduler must be an address such as tcp://host:8786, got {self.scheduler!r}"
                )
            scheduler_address(self.scheduler)
        t = self.threads
        if t is not None and (isinstance(t, bool) or not isinstance(t, int) or t < 1):
            raise InputError(f"threads must be an integer >= 1, got {t!r}")
        if isinstance(self.retries, bool) or not isinstance(self.retries, int) or self.retries < 0:
            raise InputError(f"retries must be an integer >= 0, got {self.retries!r}")

    @property
    def n_workers(self) -> int:
        """Local worker processes (``"auto"`` resolved to the cores)."""
        return available_cores() if self.workers == "auto" else int(self.workers)

    @property
    def in_process(self) -> bool:
        """Whether the frames run in this process (no Dask)."""
        return self.scheduler is None and self.n_workers == 1

    def worker_threads(self) -> int | None:
        """Compute threads of one worker process (None: the worker's own default)."""
        if self.threads is not None:
            return self.threads
        if self.scheduler is not None:
            return None
        return max(1, available_cores() // self.n_workers)

    def capped(
        self,
        *,
        per_worker_bytes: int | None = None,
        by_cores: bool = True,
        what: str | None = None,
    ) -> Parallel:
        """This setting with its local workers capped to what the machine holds.

        At most one worker per core (``by_cores``) and as many as the available memory holds
        at ``per_worker_bytes`` each (at least :data:`WORKER_BASE_BYTES`); one worker: the
        frames run in this process. A warning names the workers asked for and used when it
        caps them. An existing scheduler, or one worker, is returned as it is.

        Parameters
        ----------
        per_worker_bytes : int, optional
            Memory one worker needs (bytes), e.g. from :func:`memory_per_worker`; default
            :data:`WORKER_BASE_BYTES`.
        by_cores : bool
            Also cap by :func:`~hrvbase.threads.available_cores`.
        what : str, optional
            How the warning names the request (``"--workers 100"``); default ``"N local
            workers"``.

        Returns
        -------
        Parallel
            ``self``, or a copy with fewer ``workers``.
        """
        if self.in_process or self.scheduler is not None:
            return self
        n = self.n_workers
        per = max(WORKER_BASE_BYTES, int(per_worker_bytes or 0))
        memory = available_memory_bytes()
        cores = available_cores()
        used = max(1, min(n, memory // per, cores if by_cores else n))
        if used >= n:
            return self
        log.warning(
            "%s: using %d local worker%s (%s%s of memory available, about %s per worker)",
            what or f"{n} local workers",
            used,
            "" if used == 1 else "s",
            f"{cores} cores; " if by_cores else "",
            _gib(memory),
            _gib(per),
        )
        return dataclasses.replace(self, workers=used)

    def describe(self) -> str:
        """``"in process"``, ``"2 local workers × 1 thread"`` or ``"scheduler tcp://…"``."""
        if self.scheduler is not None:
            return f"Dask scheduler {self.scheduler}"
        if self.in_process:
            return "in process"
        t = self.worker_threads()
        return f"{self.n_workers} local Dask workers × {t} thread{'s' if t != 1 else ''}"


def available_memory_bytes() -> int:
    """Memory available to new processes (bytes): the system's available memory, within the
    memory limit of this process's control group or resource limits where one is set."""
    import psutil
    from distributed.system import MEMORY_LIMIT

    return int(min(psutil.virtual_memory().available, MEMORY_LIMIT))


def _nbytes(obj: Any) -> int:
    """Size of ``obj`` when sent to a worker (bytes; its arrays' buffers are not copied to
    count them); 0 for an object that cannot be sent."""
    import pickle

    buffers: list = []
    try:
        n = len(pickle.dumps(obj, protocol=5, buffer_callback=buffers.append))
    except Exception:  # not picklable: nothing to count (a worker would fail on it anyway)
        return 0
    return n + sum(memoryview(b).nbytes for b in buffers)


def memory_per_worker(context: WorkerContext | None) -> int:
    """Estimate of the memory one worker needs for a frame map (bytes).

    :data:`WORKER_BASE_BYTES` plus twice the size of the context's arguments (the copy sent
    to the worker, and what ``build`` makes of it: a projector from a PSF bank is of the
    bank's size). A frame's own arrays beyond the base are not counted.
    """
    extra = 0 if context is None else 2 * _nbytes(context.args)
    return WORKER_BASE_BYTES + extra


def _gib(n: int) -> str:
    return f"{n / 2**30:.2f} GiB"


@dataclass(frozen=True)
class WorkerContext:
    """A shared read-only input built once per process: ``build(*args)``.

    ``build`` must be a module-level function (workers import it by name) and ``args``
    picklable; they are sent to every worker once. The built object is kept for the life of
    the worker process, keyed by ``key`` (default: a fresh id per :class:`WorkerContext`); in
    process it is dropped (and its ``close()`` called, if it has one) when the map ends.
    """

    build: Callable[..., Any]
    args: tuple = ()
    key: str = ""

    def __post_init__(self) -> None:
        if not self.key:
            object.__setattr__(self, "key", uuid.uuid4().hex)


#: Contexts built in this process, by key (one per worker process and context).
_BUILT: dict[str, Any] = {}
_BUILD_LOCK = threading.Lock()
#: At most this many contexts are kept per process (the oldest is dropped first).
_MAX_BUILT = 4


def _context(key: str, build: Callable[..., Any], args: tuple) -> Any:
    with _BUILD_LOCK:
        if key not in _BUILT:
            while len(_BUILT) >= _MAX_BUILT:
                _BUILT.pop(next(iter(_BUILT)))
            t0 = time.perf_counter()
            _BUILT[key] = build(*args)
            log.debug("context %s built in %.2f s", key[:8], time.perf_counter() - t0)
        return _BUILT[key]


class _Failed:
    """A frame that raised an :class:`HrvError` (returned, not raised: not retried)."""

    def __init__(self, exc: BaseException) -> None:
        self.exc = exc


class _Skipped:
    """A frame not started because its map had stopped on another frame's failure."""


#: Maps (their tokens) stopped in this worker process: their frames not yet started are
#: skipped (:meth:`FrameMap._stop`).
_STOPPED: set[str] = set()


def _stop_map(token: str, dask_worker=None) -> None:
    """(On a worker) skip the frames of map ``token`` that have not started."""
    _STOPPED.add(token)


#: Loggers whose messages on a worker are sent back with the frame's result and logged by the
#: calling process (so that a command shows a frame's warnings wherever the frame ran).
FORWARDED_LOGGERS = ("hrvbase", "lfsim", "recon", "track", "hrvptm")


class _Captured(logging.Handler):
    """Collects the records of one thread (the frame's) as ``(logger, level, message)``."""

    def __init__(self) -> None:
        super().__init__()
        self.thread = threading.get_ident()
        self.records: list[tuple[str, int, str]] = []

    def emit(self, record: logging.LogRecord) -> None:
        if record.thread == self.thread:
            self.records.append((record.name, record.levelno, record.getMessage()))


@dataclass(frozen=True)
class _Done:
    """A frame's result (or :class:`_Failed`) with the log records it made on the worker."""

    result: Any
    logs: list


def _run_task(func, item, key: str | None, build, args, levels: dict, token: str) -> _Done:
    """What a worker runs for one frame: its log records (at the caller's ``levels``) are
    returned with its result; nothing is run once map ``token`` has stopped."""
    if token in _STOPPED:
        return _Done(_Skipped(), [])
    handler = _Captured()
    for name, level in levels.items():
        lg = logging.getLogger(name)
        lg.setLevel(level)
        lg.addHandler(handler)
    try:
        ctx = None if key is None else _context(key, build, args)
        try:
            result = func(item, ctx)
        except HrvError as exc:
            result = _Failed(exc)
    finally:
        for name in levels:
            logging.getLogger(name).removeHandler(handler)
    return _Done(result, handler.records)


def _replay(logs: list) -> None:
    """Log here what a frame logged on a worker."""
    for name, level, message in logs:
        logging.getLogger(name).log(level, "%s", message)


def _peak_rss_bytes() -> int:
    """Peak resident memory of this process (bytes)."""
    import resource

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(peak if sys.platform == "darwin" else peak * 1024)


def _mib(n: int) -> str:
    return f"{n / 2**20:.0f} MiB"


class FrameMap:
    """Iterable of ``(item, result)`` of :func:`frame_map`, in completion order.

    Use it as a context manager (or iterate it to the end) so that a local cluster is always
    stopped. After the iteration, :attr:`peak_memory_bytes` maps each worker (its address;
    ``"main"`` in process) to its peak resident memory in bytes.
    """

    def __init__(
        self,
        func: Callable[[Any, Any], Any],
        items: Sequence,
        *,
        parallel: Parallel | None = None,
        context: WorkerContext | None = None,
        progress: bool = False,
        desc: str = "frames",
        unit: str = "frame",
    ) -> None:
        self.func = func
        self.items = list(items)
        self.parallel = parallel or Parallel()
        self.context = context
        self.progress = progress
        self.desc = desc
        self.unit = unit
        self.peak_memory_bytes: dict[str, int] = {}
        self._cluster = None
        self._client = None
        self._iter: Iterator | None = None

    # -- context manager ---------------------------------------------------------------------
    def __enter__(self) -> FrameMap:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __iter__(self) -> Iterator[tuple[Any, Any]]:
        if self._iter is None:
            self._iter = self._run()
        return self._iter

    def close(self) -> None:
        """Stop the map (cancel frames not finished) and any cluster it started."""
        if self._iter is not None:
            self._iter.close()
        self._shutdown()

    # -- running -----------------------------------------------------------------------------
    def _bar(self):
        from tqdm.auto import tqdm

        # On stderr, shown on a terminal only (not in a log file or a captured stream).
        return tqdm(
            total=len(self.items),
            desc=self.desc,
            unit=self.unit,
            disable=None if self.progress else True,
            file=sys.stderr,
        )

    def _run(self) -> Iterator[tuple[Any, Any]]:
        if not self.items:
            return
        par = self.parallel
        if not par.in_process and par.scheduler is None:
            # A local cluster: no more workers than the memory holds with this map's context.
            self.parallel = par.capped(
                per_worker_bytes=memory_per_worker(self.context), by_cores=False
            )
        if self.parallel.in_process:
            yield from self._run_here()
        else:
            yield from self._run_dask()

    def _run_here(self) -> Iterator[tuple[Any, Any]]:
        ctx = None
        if self.context is not None:
            ctx = _context(self.context.key, self.context.build, self.context.args)
        with self._bar() as bar:
            try:
                for item in self.items:
                    result = self.func(item, ctx)
                    bar.update(1)
                    yield item, result
            finally:
                if self.context is not None:
                    _BUILT.pop(self.context.key, None)
                    close = getattr(ctx, "close", None)
                    if callable(close):  # e.g. files the context keeps open
                        close()
                self.peak_memory_bytes = {"main": _peak_rss_bytes()}
                log.info("peak memory: %s", _mib(self.peak_memory_bytes["main"]))

    def _connect(self):
        from distributed import Client

        par = self.parallel
        if par.scheduler is not None:
            self._client = _open_client(par.scheduler)
            n = len(self._client.scheduler_info().get("workers", {}))
            log.info("Dask scheduler %s: %d worker(s)", par.scheduler, n)
            if n == 0:
                log.warning(
                    "Dask scheduler %s has no workers yet; frames wait until one joins",
                    par.scheduler,
                )
            return
        self._cluster = _local_cluster(par)
        self._client = Client(self._cluster, set_as_default=False)
        log.info("started %s", par.describe())

    def _shutdown(self) -> None:
        client, cluster = self._client, self._cluster
        self._client = self._cluster = None
        if client is not None:
            try:
                client.close()
            except Exception as exc:  # pragma: no cover - best effort
                log.debug("closing the Dask client: %s", exc)
        if cluster is not None:
            try:
                cluster.close()
            except Exception as exc:  # pragma: no cover - best effort
                log.debug("closing the local cluster: %s", exc)

    def _collect_peaks(self) -> None:
        try:
            peaks = self._client.run(_peak_rss_bytes)
        except Exception as exc:  # a worker gone at the end: report what answers
            log.debug("peak memory of the workers: %s", exc)
            return
        self.peak_memory_bytes = {str(k): int(v) for k, v in peaks.items()}
        log.info(
            "peak memory per worker: %s",
            ", ".join(f"{k} {_mib(v)}" for k, v in sorted(self.peak_memory_bytes.items())),
        )

    def _stop(self, token: str) -> None:
        """After a failure: the frames not started are skipped, those running finish (and are
        handed back), so that every frame written is recorded and no worker writes a frame
        after the map has ended.

        The frames are not cancelled: a worker cannot stop a frame it has begun, and the
        scheduler may start a queued one while its cancellation is on the way."""
        try:
            self._client.run(_stop_map, token)
        except Exception as exc:  # pragma: no cover - a worker gone: its frames were lost
            log.debug("stopping the frames on the workers: %s", exc)

    def _run_dask(self) -> Iterator[tuple[Any, Any]]:
        from distributed import as_completed

        self._connect()
        client = self._client
        token = uuid.uuid4().hex[:8]
        first_error: BaseException | None = None
        try:
            key = build = None
            shared = [None]  # the context's arguments on the workers (sent again if lost)

            def share():
                # One copy on every worker, sent once (not once per frame).
                [shared[0]] = client.scatter([self.context.args], broadcast=True, hash=False)

            if self.context is not None:
                key, build = self.context.key, self.context.build
                share()
            levels = {n: logging.getLogger(n).getEffectiveLevel() for n in FORWARDED_LOGGERS}
            futures = {}
            resubmitted: dict[int, int] = {}

            def submit(i: int):
                n = resubmitted.get(i, 0)
                fut = client.submit(
                    _run_task,
                    self.func,
                    self.items[i],
                    key,
                    build,
                    shared[0],
                    levels,
                    token,
                    key=f"{self.desc}-{i:06d}-{token}" + (f"-r{n}" if n else ""),
                    retries=self.parallel.retries,
                    pure=False,
                )
                futures[fut] = i
                return fut

            for i in range(len(self.items)):
                submit(i)
            with self._bar() as bar:
                completed = as_completed(list(futures), loop=client.loop)
                for fut in completed:
                    i = futures[fut]
                    if first_error is not None and fut.status != "finished":
                        continue
                    try:
                        done = fut.result()
                        _replay(done.logs)
                        result = done.result
                    except CancelledError as exc:
                        # Not cancelled by this map: the frame finished on a worker that
                        # died before its result was fetched, and the scheduler dropped it.
                        # Run it again (a frame writes its output atomically).
                        if first_error is None and resubmitted.get(i, 0) < self.parallel.retries:
                            resubmitted[i] = resubmitted.get(i, 0) + 1
                            if shared[0] is not None and shared[0].status != "finished":
                                # The context went with its worker(s) ("lost dependencies"):
                                # frames depending on it cannot run until it is sent again.
                                log.warning("the frames' shared context was lost; sending it again")
                                share()
                            log.warning(
                                "%s %d: its result was lost with its worker; running it again",
                                self.unit,
                                i,
                            )
                            completed.add(submit(i))
                            continue
                        result = _Failed(exc)
                    except Exception as exc:  # an unexpected error, after its retries
                        result = _Failed(exc)
                    if isinstance(result, _Skipped):
                        continue
                    if isinstance(result, _Failed):
                        if first_error is None:
                            first_error = result.exc
                            self._stop(token)
                        continue
                    bar.update(1)
                    yield self.items[i], result
            if first_error is not None:
                raise first_error
            self._collect_peaks()
        finally:
            self._shutdown()


@contextmanager
def _sigint_blocked() -> Iterator[None]:
    """Run the block with SIGINT blocked in this thread (POSIX; elsewhere nothing is done).

    Threads started meanwhile, and the processes they start, inherit the blocked signal: the
    worker processes of a local cluster (started by its event loop's threads) never take the
    SIGINT a terminal sends to the whole process group on Ctrl-C. This process alone is
    interrupted and stops its workers. A Ctrl-C pressed inside the block is delivered when it
    ends.

    Python's resource tracker is started first: starting it unblocks SIGINT in the thread
    that starts it (``multiprocessing.resource_tracker``), which would be a worker's."""
    if not hasattr(signal, "pthread_sigmask"):  # pragma: no cover - Windows
        yield
        return
    from multiprocessing import resource_tracker

    resource_tracker.ensure_running()
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _local_cluster(par: Parallel):
    """Start the local cluster of ``par`` (``n_workers`` processes, ``worker_threads()``
    cores each, one frame at a time per process), its workers deaf to Ctrl-C
    (:func:`_sigint_blocked`): on an interrupt, the caller stops them."""
    from distributed import LocalCluster

    cluster = None
    try:
        with _sigint_blocked(), warnings.catch_warnings():
            # Its scheduler's HTTP server (no dashboard) takes another port when 8787 is
            # taken (another Dask cluster on this machine): nothing to tell the user.
            warnings.filterwarnings("ignore", "Port .* is already in use", UserWarning)
            cluster = LocalCluster(
                n_workers=par.n_workers,
                threads_per_worker=1,  # one frame at a time per process; it uses `threads` cores
                processes=True,
                memory_limit=par.memory_limit if par.memory_limit is not None else 0,
                dashboard_address=None,
                # Dask's own log lines are not the user's: a worker's heartbeat that
                # fails while a loaded machine shuts the cluster down logs an ERROR; the
                # frames' failures reach the user through frame_map's results.
                silence_logs=logging.CRITICAL,
                env={"HRVPTM_THREADS": str(par.worker_threads())},
            )
    except BaseException:  # e.g. Ctrl-C pressed while the workers started
        if cluster is not None:
            cluster.close()
        raise
    return cluster


@contextmanager
def shared_cluster(parallel: Parallel | None) -> Iterator[Parallel | None]:
    """One local cluster for several frame maps (e.g. every stage of a study).

    For a ``parallel`` that would start a local cluster in every :func:`frame_map`
    (``workers > 1``, no ``scheduler``), starts it once and yields a
    :class:`Parallel` that uses it (its ``scheduler``, the same threads per worker and
    retries), stopping it on exit. Any other ``parallel`` (None, in process, an existing
    scheduler) is yielded as it is. The results are the same either way; a worker keeps the
    peak memory of every map run on it.
    """
    if parallel is not None:
        parallel = parallel.capped(by_cores=False)
    if parallel is None or parallel.in_process or parallel.scheduler is not None:
        yield parallel
        return
    t0 = time.perf_counter()
    cluster = _local_cluster(parallel)
    log.info("started %s (shared) in %.1f s", parallel.describe(), time.perf_counter() - t0)
    try:
        yield dataclasses.replace(
            parallel,
            scheduler=cluster.scheduler_address,
            threads=parallel.worker_threads(),
        )
    finally:
        try:
            cluster.close()
        except Exception as exc:  # pragma: no cover - best effort
            log.debug("closing the shared local cluster: %s", exc)


def frame_map(
    func: Callable[[Any, Any], Any],
    items: Iterable,
    *,
    parallel: Parallel | None = None,
    context: WorkerContext | None = None,
    progress: bool = False,
    desc: str = "frames",
    unit: str = "frame",
) -> FrameMap:
    """Run ``func(item, context)`` for every item; ``(item, result)`` pairs as they complete.

    Parameters
    ----------
    func : callable
        ``func(item, ctx) -> result``; a module-level function (Dask workers import it), its
        result picklable. It must not depend on which process runs it (seed random numbers
        per item), so that every way of running gives the same results.
    items : iterable
        One per frame (picklable, small: a frame index or reference).
    parallel : Parallel, optional
        Default ``Parallel()``: in this process, in order.
    context : WorkerContext, optional
        Shared read-only input, built once per process and passed as ``ctx`` (None without).
    progress : bool
        tqdm progress bar of the frames completed, on stderr when it is a terminal.
    desc, unit : str
        Progress bar label and unit; ``desc`` also names the Dask tasks.

    Returns
    -------
    FrameMap
        Iterable of ``(item, result)`` in completion order (item order in process); use it as
        a context manager.

    Raises
    ------
    InputError
        (On iteration) the scheduler cannot be reached.
    HrvError
        (On iteration) the first frame that failed, after the frames that finished.
    """
    return FrameMap(
        func,
        list(items),
        parallel=parallel,
        context=context,
        progress=progress,
        desc=desc,
        unit=unit,
    )


def in_order(pairs: Iterable[tuple[Any, Any]], items: Sequence) -> Iterator[tuple[Any, Any]]:
    """Reorder ``(item, result)`` pairs into the order of ``items`` (distinct, hashable): each
    is yielded as soon as it and every item before it have arrived."""
    position = {item: i for i, item in enumerate(items)}
    waiting: dict[int, tuple[Any, Any]] = {}
    nxt = 0
    for item, result in pairs:
        waiting[position[item]] = (item, result)
        while nxt in waiting:
            yield waiting.pop(nxt)
            nxt += 1


__all__ = [
    "CONNECT_TIMEOUT_S",
    "SCHEDULER_SCHEMES",
    "WORKER_BASE_BYTES",
    "FrameMap",
    "Parallel",
    "WorkerContext",
    "available_cores",
    "available_memory_bytes",
    "check_scheduler",
    "frame_map",
    "in_order",
    "memory_per_worker",
    "scheduler_address",
    "shared_cluster",
]
