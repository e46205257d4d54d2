"""hrvbase.parallel: the frame map in process, on a local cluster and on a loopback cluster
started by the test (``dask scheduler`` + two ``dask worker`` processes), a killed worker, and
the command-line options."""

from __future__ import annotations

import argparse
import os
import select
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from hrvbase.cli import add_parallel_options, parallel_from_args
from hrvbase.errors import InputError
from hrvbase.parallel import Parallel, WorkerContext, frame_map, in_order, shared_cluster
from tests.helpers import LoopbackCluster


# -- per-frame functions (module level: the workers import them) ---------------------------
def _build(offset, folder):
    """The shared context: records each build (one line per process and context)."""
    with open(Path(folder) / "builds.txt", "a") as fh:
        fh.write(f"{os.getpid()}\n")
    return {"offset": offset, "bank": np.arange(1000.0)}


def _frame(k, ctx):
    """A seeded computation per frame (the same whatever process runs it)."""
    rng = np.random.default_rng([7, k])
    x = rng.normal(size=500) + ctx["offset"]
    return float(np.sum(x * ctx["bank"][:500])), os.getpid()


def _warning_frame(k, ctx):
    import logging

    logging.getLogger("hrvbase.test").warning("frame %d: a warning on the worker", k)
    logging.getLogger("hrvbase.test").debug("frame %d: a debug message", k)
    return k


def _slow_frame(k, ctx):
    time.sleep(0.8)
    Path(ctx["folder"], f"done_{k}").write_text("")
    return k * k


def _slow_ctx(folder):
    return {"folder": folder}


def _fail_on_3(k, ctx):
    with open(Path(ctx["folder"]) / "attempts.txt", "a") as fh:
        fh.write(f"{k}\n")
    if k == 3:
        raise InputError(f"frame {k} is unreadable")
    return k


def _write_or_fail_on_1(k, ctx):
    """Frame 1 fails at once; the others take a while and write their output."""
    if k == 1:
        raise InputError(f"frame {k} is unreadable")
    time.sleep(0.3)
    Path(ctx["folder"], f"done_{k}").write_text("")
    return k


def _sleepy_frame(k, ctx):
    time.sleep(0.5)
    return k


def _expected(n, offset):
    return [_frame(k, {"offset": offset, "bank": np.arange(1000.0)})[0] for k in range(n)]


# -- settings and options -------------------------------------------------------------------
@pytest.mark.parametrize("workers", [0, -1, 1.5, "two", True])
def test_parallel_refuses_bad_workers(workers):
    with pytest.raises(InputError, match="workers must be an integer >= 1"):
        Parallel(workers=workers)


def test_parallel_settings():
    assert Parallel().in_process
    assert Parallel(workers=1).describe() == "in process"
    p = Parallel(workers=2, threads=3)
    assert not p.in_process and p.worker_threads() == 3
    assert Parallel(workers=2).worker_threads() >= 1
    assert not Parallel(scheduler="tcp://127.0.0.1:1").in_process
    with pytest.raises(InputError, match="scheduler must be an address"):
        Parallel(scheduler=" ")


def _parse(argv):
    p = argparse.ArgumentParser()
    add_parallel_options(p)
    return p.parse_args(argv)


@pytest.mark.parametrize("value", ["0", "-2", "x", ""])
def test_cli_workers_error_names_the_option(value):
    with pytest.raises(InputError, match=r"^--workers must be an integer >= 1 or 'auto'"):
        parallel_from_args(_parse([f"--workers={value}"]))


def test_cli_options(monkeypatch):
    from hrvbase.parallel import WORKER_BASE_BYTES

    _machine(monkeypatch, 8, 100 * WORKER_BASE_BYTES)
    assert parallel_from_args(_parse([])) == Parallel()
    assert parallel_from_args(_parse(["--workers", "3"]), threads=2) == Parallel(3, threads=2)
    assert parallel_from_args(_parse(["--workers", "auto"])).n_workers >= 1
    checked = []
    monkeypatch.setattr("hrvbase.parallel.check_scheduler", lambda *a: checked.append(a))
    got = parallel_from_args(_parse(["--scheduler", "tcp://h:1"]))
    assert got.scheduler == "tcp://h:1" and checked == [("tcp://h:1", "--scheduler")]


def test_unreachable_scheduler_names_the_option(monkeypatch):
    monkeypatch.setattr("hrvbase.scheduler.CONNECT_TIMEOUT_S", 2.0)
    par = Parallel(scheduler="tcp://127.0.0.1:9")  # discard port: nothing listens
    with pytest.raises(InputError, match=r"^--scheduler tcp://127.0.0.1:9: nothing is listening"):
        list(frame_map(_frame, range(2), parallel=par))


#: A command line of frames in parallel (run by the tests in a subprocess): ``demo run
#: [--workers N | --scheduler ADDRESS] [--frames N]`` prints each frame's index as it completes.
DEMO = """
import sys
from hrvbase.cli import Parser, add_parallel_options, common_options, parallel_from_args, run_main
from hrvbase.parallel import frame_map
from tests.hrvbase.test_parallel import _sleepy_frame

def go(args):
    with frame_map(_sleepy_frame, range(args.frames), parallel=parallel_from_args(args)) as fm:
        for k, _ in fm:
            print(k, flush=True)
    return 0

p = Parser(prog="demo", parents=[common_options(suppress=False)])
sub = p.add_subparsers(parser_class=Parser)
c = sub.add_parser("run", parents=[common_options(suppress=True)])
add_parallel_options(c)
c.add_argument("--frames", type=int, default=2)
c.set_defaults(func=go)
sys.exit(run_main("demo", p, None, loggers=("demo",)))
"""

ROOT = Path(__file__).resolve().parents[2]


def _demo(*argv: str, timeout: float = 120.0) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", DEMO, "run", *argv],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


class _Service:
    """A TCP service on a free port of 127.0.0.1 that is not a Dask scheduler: it answers every
    connection with ``reply`` (``None``: says nothing) and closes it after ``hold_s``."""

    def __init__(self, reply: bytes | None, hold_s: float = 30.0) -> None:
        self.reply, self.hold_s = reply, hold_s
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.sock.settimeout(0.2)
        self.address = f"tcp://127.0.0.1:{self.sock.getsockname()[1]}"
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._serve, daemon=True)

    def _serve(self) -> None:
        conns = []
        t0 = time.monotonic()
        while not self.stop.is_set() and time.monotonic() - t0 < self.hold_s:
            try:
                conn, _ = self.sock.accept()
            except TimeoutError:
                continue
            conns.append(conn)
            if self.reply is not None:
                try:
                    conn.sendall(self.reply)
                except OSError:
                    pass
        for conn in conns:
            conn.close()
        self.sock.close()

    def __enter__(self) -> _Service:
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop.set()
        self.thread.join(5)


def _closed_port() -> int:
    """A port of 127.0.0.1 on which nothing listens."""
    with socket.create_server(("127.0.0.1", 0)) as s:
        return s.getsockname()[1]


def _one_error_line(res: subprocess.CompletedProcess, needle: str) -> None:
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.returncode == 2, res.stderr
    assert len(lines) == 1 and lines[0].startswith("demo: error: --scheduler "), res.stderr
    assert needle in lines[0], lines[0]


@pytest.mark.parametrize(
    ("address", "needle"),
    [
        ("banana", "expected tcp://HOST:PORT"),
        ("tcp://127.0.0.1", "expected tcp://HOST:PORT"),
        ("tcp://127.0.0.1:0", "port"),
        ("tcp://127.0.0.1:70000", "port"),
        ("tcp://127.0.0.1:http", "port"),
        ("tcp://:8786", "host"),
        ("http://127.0.0.1:8786", "scheme"),
        ("tcp://127.0.0.1:8786/path", "expected tcp://HOST:PORT"),
    ],
)
def test_scheduler_address_form_is_checked_before_connecting(address, needle):
    with pytest.raises(InputError, match=r"^--scheduler ") as err:
        parallel_from_args(_parse(["--scheduler", address]))
    assert needle in str(err.value)
    with pytest.raises(InputError, match=r"^scheduler "):
        Parallel(scheduler=address)


def test_scheduler_without_a_port_is_one_line_without_traceback():
    t0 = time.monotonic()
    res = _demo("--scheduler", "banana")
    _one_error_line(res, "banana")
    assert time.monotonic() - t0 < 15


@pytest.mark.parametrize(
    ("reply", "needle"),
    [
        (b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n" * 4, "not a Dask scheduler"),
        (b"SSH-2.0-OpenSSH_9.6\r\n", "not a Dask scheduler"),
        (None, "no answer"),
    ],
    ids=["http", "ssh", "silent"],
)
def test_a_service_that_is_not_dask_is_refused_in_one_line(reply, needle):
    """A scheduler address answered by another service: one error line, quickly, no
    traceback (nor an attempt to allocate the length its first bytes would give)."""
    with _Service(reply) as svc:
        t0 = time.monotonic()
        res = _demo("--scheduler", svc.address, timeout=60)
        elapsed = time.monotonic() - t0
    _one_error_line(res, needle)
    assert svc.address in res.stderr and "EiB" not in res.stderr
    assert elapsed < 20, elapsed


@pytest.mark.parametrize("workers", ["2", "1", "auto"])
def test_workers_and_scheduler_together_are_refused(workers):
    """With --scheduler the frames run on that cluster's workers: --workers contradicts it
    (refused before any connection)."""
    argv = ["--workers", workers, "--scheduler", f"tcp://127.0.0.1:{_closed_port()}"]
    with pytest.raises(InputError, match=r"^--workers and --scheduler exclude each other"):
        parallel_from_args(_parse(argv))


def test_nothing_listening_fails_fast():
    addr = f"tcp://127.0.0.1:{_closed_port()}"
    t0 = time.monotonic()
    with pytest.raises(InputError, match=r"^--scheduler .*nothing is listening"):
        parallel_from_args(_parse(["--scheduler", addr]))
    assert time.monotonic() - t0 < 2


def _machine(monkeypatch, cores: int, memory_bytes: int) -> None:
    """Pretend this machine has ``cores`` cores and ``memory_bytes`` of available memory."""
    monkeypatch.setattr("hrvbase.parallel.available_cores", lambda: cores)
    monkeypatch.setattr("hrvbase.parallel.available_memory_bytes", lambda: memory_bytes)


def test_cli_workers_are_capped_by_the_cores(monkeypatch, caplog):
    import logging

    from hrvbase.parallel import WORKER_BASE_BYTES

    _machine(monkeypatch, 2, 1000 * WORKER_BASE_BYTES)
    caplog.set_level(logging.WARNING, logger="hrvbase")
    par = parallel_from_args(_parse(["--workers", "100"]))
    assert par.n_workers == 2 and par.worker_threads() == 1
    [msg] = [r.getMessage() for r in caplog.records]
    assert msg.startswith("--workers 100: using 2 local workers (2 cores"), msg
    caplog.clear()
    assert parallel_from_args(_parse(["--workers", "2"])).n_workers == 2  # no warning
    assert parallel_from_args(_parse(["--workers", "auto"])).n_workers == 2
    assert not caplog.records


def test_cli_workers_are_capped_by_the_available_memory(monkeypatch, caplog):
    import logging

    from hrvbase.parallel import WORKER_BASE_BYTES

    _machine(monkeypatch, 16, 3 * WORKER_BASE_BYTES + 1)
    caplog.set_level(logging.WARNING, logger="hrvbase")
    assert parallel_from_args(_parse(["--workers", "8"])).n_workers == 3
    assert parallel_from_args(_parse(["--workers", "auto"])).n_workers == 3
    msgs = [r.getMessage() for r in caplog.records]
    assert msgs[0].startswith("--workers 8: using 3 local workers"), msgs
    assert msgs[1].startswith("--workers auto: using 3 local workers"), msgs
    _machine(monkeypatch, 16, WORKER_BASE_BYTES // 2)  # not even one: in this process
    assert parallel_from_args(_parse(["--workers", "4"])).in_process


def test_the_cap_warning_is_one_line_of_the_command(monkeypatch, capsys):
    from hrvbase.cli import Parser, common_options, run_main
    from hrvbase.parallel import WORKER_BASE_BYTES

    _machine(monkeypatch, 2, 1000 * WORKER_BASE_BYTES)
    seen = []
    p = Parser(prog="demo", parents=[common_options(suppress=False)])
    sub = p.add_subparsers(parser_class=Parser)
    c = sub.add_parser("run", parents=[common_options(suppress=True)])
    add_parallel_options(c)
    c.set_defaults(func=lambda args: seen.append(parallel_from_args(args)))
    assert run_main("demo", p, ["run", "--workers", "1000000000"], loggers=("demo",)) == 0
    assert seen == [Parallel(workers=2)]
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("demo: warning: --workers 1000000000: using 2 "), err


def _big_context(_array):
    return {"offset": 0.0, "bank": np.arange(1000.0)}


def test_frame_map_caps_the_workers_by_the_memory_its_job_needs(monkeypatch, caplog):
    """A context of 200 MB sent to every worker: with memory for the base and one copy only,
    the frames run in this process, with a warning."""
    import logging

    from hrvbase.parallel import WORKER_BASE_BYTES

    big = np.zeros(200 * 2**20, np.uint8)
    _machine(monkeypatch, 16, WORKER_BASE_BYTES + 2 * big.nbytes + 2**20)
    caplog.set_level(logging.WARNING, logger="hrvbase")
    ctx = WorkerContext(_big_context, (big,))
    with frame_map(_frame, range(3), parallel=Parallel(workers=4), context=ctx) as fm:
        got = dict(fm)
    assert {pid for _, pid in got.values()} == {os.getpid()}
    assert fm.parallel.in_process
    [msg] = [r.getMessage() for r in caplog.records]
    assert msg.startswith("4 local workers: using 1 local worker"), msg


# -- in process ----------------------------------------------------------------------------
def test_in_process_runs_in_order_without_dask(tmp_path):
    code = (
        "import sys; from hrvbase.parallel import frame_map, WorkerContext; "
        "from tests.hrvbase.test_parallel import _frame, _build; "
        f"ctx = WorkerContext(_build, (2.0, {str(tmp_path)!r})); "
        "out = list(frame_map(_frame, range(4), context=ctx)); "
        "print([k for k, _ in out]); print(sorted(m for m in sys.modules if 'dask' in m "
        "or m == 'distributed'))"
    )
    root = Path(__file__).resolve().parents[2]
    res = subprocess.run(
        [sys.executable, "-c", code], cwd=root, capture_output=True, text=True, check=True
    )
    assert res.stdout.splitlines() == ["[0, 1, 2, 3]", "[]"]
    assert len((tmp_path / "builds.txt").read_text().split()) == 1


class _Counted:
    """Counts how often it is pickled."""

    pickled = 0

    def __reduce__(self):
        type(self).pickled += 1
        return (_Counted, ())


def _counted_context(_obj):
    return {"offset": 0.0, "bank": np.arange(1000.0)}


def test_in_process_map_never_pickles_its_context():
    """Its context is neither sent nor measured (a large PSF bank, an unpicklable scene)."""
    _Counted.pickled = 0
    ctx = WorkerContext(_counted_context, (_Counted(),))
    assert len(list(frame_map(_frame, range(2), context=ctx))) == 2
    assert _Counted.pickled == 0


def test_in_process_failure_stops_at_the_frame(tmp_path):
    ctx = WorkerContext(_slow_ctx, (str(tmp_path),))
    got = []
    with pytest.raises(InputError, match="frame 3 is unreadable"):
        for _k, r in frame_map(_fail_on_3, range(6), context=ctx):
            got.append(r)
    assert got == [0, 1, 2]
    assert (tmp_path / "attempts.txt").read_text().split() == ["0", "1", "2", "3"]


def test_in_order():
    pairs = [(2, "c"), (0, "a"), (3, "d"), (1, "b")]
    assert [k for k, _ in in_order(pairs, [0, 1, 2, 3])] == [0, 1, 2, 3]


# -- local cluster ---------------------------------------------------------------------------
def test_local_cluster_same_results_context_once_per_worker(tmp_path):
    n = 8
    ctx = WorkerContext(_build, (2.0, str(tmp_path)))
    with frame_map(_frame, range(n), parallel=Parallel(workers=2), context=ctx) as fm:
        got = dict(fm)
    assert sorted(got) == list(range(n))
    assert [got[k][0] for k in range(n)] == _expected(n, 2.0)  # bit for bit
    pids = {pid for _, pid in got.values()}
    assert os.getpid() not in pids and 1 <= len(pids) <= 2
    builds = (tmp_path / "builds.txt").read_text().split()
    assert sorted(set(builds)) == sorted(builds)  # at most once per process
    assert set(map(int, builds)) == pids
    assert len(fm.peak_memory_bytes) == 2
    assert all(v > 10 * 2**20 for v in fm.peak_memory_bytes.values())


def test_shared_cluster_serves_several_maps(tmp_path):
    """One local cluster for maps in a row (a study's stages): the same worker processes, the
    same results; stopped on exit. Other settings pass through unchanged."""
    for par in (None, Parallel(), Parallel(scheduler="tcp://10.0.0.5:8786")):
        with shared_cluster(par) as got:
            assert got is par
    n = 6
    with shared_cluster(Parallel(workers=2)) as par:
        assert par.scheduler.startswith("tcp://127.0.0.1") and par.worker_threads() >= 1
        pids = []
        for offset in (1.0, 3.0):
            ctx = WorkerContext(_build, (offset, str(tmp_path)))
            with frame_map(_frame, range(n), parallel=par, context=ctx) as fm:
                got = dict(fm)
            assert [got[k][0] for k in range(n)] == _expected(n, offset)  # bit for bit
            pids.append({pid for _, pid in got.values()})
    assert os.getpid() not in pids[0] | pids[1]
    assert len(pids[0] | pids[1]) <= 2  # the same two worker processes for both maps
    with pytest.raises(InputError, match="scheduler"):  # stopped on exit
        list(frame_map(_frame, range(2), parallel=par, context=ctx))


def test_local_cluster_failure_is_raised_and_not_retried(tmp_path):
    ctx = WorkerContext(_slow_ctx, (str(tmp_path),))
    got = []
    with pytest.raises(InputError, match="frame 3 is unreadable"):
        with frame_map(_fail_on_3, range(4), parallel=Parallel(workers=2), context=ctx) as fm:
            for k, _ in fm:
                got.append(k)
    attempts = (tmp_path / "attempts.txt").read_text().split()
    assert attempts.count("3") == 1  # a user error is not retried
    assert set(got) <= {0, 1, 2}


def test_after_a_failure_every_frame_written_is_handed_back(tmp_path):
    """Frames not started when one fails are skipped; those running finish and are handed
    back, so that a command records every frame written and none is written after the map."""
    ctx = WorkerContext(_slow_ctx, (str(tmp_path),))
    got = []
    with pytest.raises(InputError, match="frame 1 is unreadable"):
        with frame_map(
            _write_or_fail_on_1, range(12), parallel=Parallel(workers=2), context=ctx
        ) as fm:
            for k, _ in fm:
                got.append(k)
    written = {int(p.name[5:]) for p in tmp_path.glob("done_*")}
    assert written == set(got) and len(got) < 11, (written, got)
    time.sleep(1.0)
    assert {int(p.name[5:]) for p in tmp_path.glob("done_*")} == written


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _interrupt_after_first_frame(*argv: str) -> tuple[int, str, float]:
    """Run the demo command in its own process group, press Ctrl-C (SIGINT to the whole
    group, as a terminal does) once a frame has completed; its exit status, stderr and the
    seconds it took to exit."""
    p = subprocess.Popen(
        [sys.executable, "-c", DEMO, "run", *argv],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        # as from a terminal: a test run started in the background (nohup, `&` in a script)
        # ignores SIGINT, which its children would inherit
        preexec_fn=_default_sigint,
    )
    try:
        ready, _, _ = select.select([p.stdout], [], [], 180)
        assert ready and p.stdout.readline().strip(), "no frame completed"
        time.sleep(0.3)  # the workers are busy with the next frames
        t0 = time.monotonic()
        os.killpg(p.pid, signal.SIGINT)
        _, err = p.communicate(timeout=90)
        return p.returncode, err, time.monotonic() - t0
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
            p.communicate()


def test_ctrl_c_with_local_workers_is_one_line(tmp_path):
    """Ctrl-C while local workers run frames: the workers do not take the terminal's SIGINT
    (no traceback of theirs); the command stops them and prints its one line, status 130."""
    rc, err, seconds = _interrupt_after_first_frame("--workers", "2", "--frames", "60")
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 130, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    assert lines[-1] == "demo: interrupted", err
    assert seconds < 60


def test_local_workers_print_nothing_when_the_dashboard_port_is_taken():
    """Another Dask cluster on this machine (its port 8787 taken): the command's stderr holds
    its own lines only."""
    try:
        taken = socket.create_server(("127.0.0.1", 8787))
    except OSError:  # taken already
        taken = None
    try:
        res = _demo("--workers", "2", "--frames", "2")
    finally:
        if taken is not None:
            taken.close()
    assert res.returncode == 0, res.stderr
    assert res.stderr == "", res.stderr


# -- a real loopback cluster -----------------------------------------------------------------
def test_loopback_cluster_same_results(tmp_path):
    n = 6
    with LoopbackCluster(tmp_path) as cluster:
        ctx = WorkerContext(_build, (1.0, str(tmp_path)))
        par = Parallel(scheduler=cluster.address)
        with frame_map(_frame, range(n), parallel=par, context=ctx) as fm:
            got = dict(fm)
    assert [got[k][0] for k in range(n)] == _expected(n, 1.0)
    assert len({pid for _, pid in got.values()} - {os.getpid()}) >= 1
    assert len(fm.peak_memory_bytes) == 2


def test_loopback_cluster_killed_worker_frames_redone(tmp_path):
    n = 6
    with LoopbackCluster(tmp_path) as cluster:
        ctx = WorkerContext(_slow_ctx, (str(tmp_path),))
        par = Parallel(scheduler=cluster.address)

        with cluster.killing_worker_when(lambda: any(tmp_path.glob("done_*"))):
            with frame_map(_slow_frame, range(n), parallel=par, context=ctx) as fm:
                got = dict(fm)
        assert cluster.workers[0].poll() is not None  # it was killed during the run
    assert got == {k: k * k for k in range(n)}
    assert len(fm.peak_memory_bytes) == 1  # the surviving worker


def _pid_frame(k, ctx):
    Path(ctx["folder"], f"done_{k}_{os.getpid()}").write_text("")
    return k * k


def test_loopback_cluster_results_lost_with_their_worker_are_redone(tmp_path):
    """Frames that finished on a worker killed before their results were fetched (the caller
    was busy with an earlier frame) are run again, not reported as cancelled."""
    n = 6
    with LoopbackCluster(tmp_path) as cluster:
        ctx = WorkerContext(_slow_ctx, (str(tmp_path),))
        par = Parallel(scheduler=cluster.address)
        got = {}
        with frame_map(_pid_frame, range(n), parallel=par, context=ctx) as fm:
            for k, v in fm:
                if not got:  # slow caller: every frame finishes while it waits
                    t0 = time.monotonic()
                    while len(list(tmp_path.glob("done_*"))) < n and time.monotonic() - t0 < 60:
                        time.sleep(0.05)
                    cluster.kill_worker(0)
                got[k] = v
        assert cluster.workers[0].poll() is not None
    assert got == {k: k * k for k in range(n)}


def _map_on_two_workers(tmp_path, n: int, retries: int) -> dict:
    """``{frame: (value, pid)}`` of ``n`` frames of :func:`_frame` on two local workers."""
    ctx = WorkerContext(_build, (1.0, str(tmp_path)))
    par = Parallel(workers=2, threads=1, retries=retries)
    with frame_map(_frame, range(n), parallel=par, context=ctx) as fm:
        return dict(fm)


def test_a_result_cancelled_by_the_scheduler_is_run_again(monkeypatch, caplog, tmp_path):
    """The scheduler may cancel a finished frame whose worker died while its result was being
    fetched ("Couldn't gather ... rescheduling", then FutureCancelledError): the map runs that
    frame again (at most ``retries`` times) instead of failing."""
    import logging

    from distributed import Future
    from distributed.client import FutureCancelledError

    real = Future.result
    lost = []

    def result(self, *a, **k):
        if "-000002-" in self.key and len(lost) < 2:  # lost twice, then fetched
            lost.append(self.key)
            raise FutureCancelledError(self.key, reason="unknown")
        return real(self, *a, **k)

    monkeypatch.setattr(Future, "result", result)
    caplog.set_level(logging.WARNING, logger="hrvbase")
    got = _map_on_two_workers(tmp_path, 4, retries=2)
    assert sorted(got) == [0, 1, 2, 3]
    assert [v for v, _ in (got[k] for k in range(4))] == _expected(4, 1.0)
    assert len(set(lost)) == 2  # a new key each time
    assert sum("running it again" in r.getMessage() for r in caplog.records) == 2
    # Beyond the retries: the map fails with the cancellation.
    lost.clear()
    with pytest.raises(FutureCancelledError):
        _map_on_two_workers(tmp_path, 4, retries=1)


def test_a_shared_context_lost_with_its_workers_is_sent_again(monkeypatch, caplog, tmp_path):
    """The frames depend on the context's arguments scattered to the workers; when every copy
    went with the workers that held it, the scheduler cancels the frames waiting on them
    ("lost dependencies"). The map sends the arguments again and reruns those frames, instead
    of resubmitting them onto the lost copy until the retries run out."""
    import logging

    from distributed import Future
    from distributed.client import FutureCancelledError

    real = Future.result
    lost = []

    def result(self, *a, **k):
        if "-000002-" in self.key and not lost:
            lost.append(self.key)
            shared = [key for key in self.client.futures if not str(key).startswith("frames-")]
            assert shared  # the scattered context
            self.client.cancel([Future(key, self.client) for key in shared])
            raise FutureCancelledError(self.key, reason="lost dependencies")
        return real(self, *a, **k)

    monkeypatch.setattr(Future, "result", result)
    caplog.set_level(logging.WARNING, logger="hrvbase")
    got = _map_on_two_workers(tmp_path, 6, retries=1)
    assert [got[k][0] for k in range(6)] == _expected(6, 1.0)
    assert lost
    messages = [r.getMessage() for r in caplog.records]
    assert any("shared context was lost" in m for m in messages)


def test_worker_messages_are_logged_here(caplog):
    import logging

    caplog.set_level(logging.WARNING, logger="hrvbase")
    with frame_map(_warning_frame, range(3), parallel=Parallel(workers=2)) as fm:
        assert sorted(k for k, _ in fm) == [0, 1, 2]
    got = sorted(r.getMessage() for r in caplog.records if r.name == "hrvbase.test")
    assert got == [f"frame {k}: a warning on the worker" for k in range(3)]
