"""Helpers shared by the test packages (plain functions; fixtures live in the conftest files)."""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path

#: The particle box of most lfsim test experiments: (x, y, z) ranges in µm.
BOX_UM = ((-150, 150), (-150, 150), (100, 300))

#: The simple shear of the lfsim tests: γ grows 0.05 a frame in the xz plane about z = 200 µm.
SHEAR_XZ = {"type": "simple_shear", "plane": "xz", "step_gamma": 0.05, "center_xyz_um": (0, 0, 200)}


def toml_value(value: object) -> str:
    """``value`` written as a TOML value: strings and paths quoted, sequences as arrays, numbers
    as Python writes them (``5`` stays ``5``, ``5.0`` stays ``5.0``)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str | Path):
        return f'"{value}"'
    if isinstance(value, Sequence):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    return repr(value)


def experiment_toml(**sections: Mapping[str, object]) -> str:
    """The text of a small experiment file: one ``[section]`` per keyword argument, in the order
    given, one ``key = value`` a line, a blank line between sections, so that a test may edit
    the text with ``str.replace``.

    A scene may be given as a placeholder such as ``"{scene}"`` that the test fills in later.

    Examples
    --------
    >>> print(experiment_toml(experiment={"name": "t", "frames": 2}, render={"rays": 10}))
    [experiment]
    name = "t"
    frames = 2
    <BLANKLINE>
    [render]
    rays = 10
    <BLANKLINE>
    """
    blocks = []
    for section, keys in sections.items():
        lines = [f"[{section}]", *(f"{key} = {toml_value(v)}" for key, v in keys.items())]
        blocks.append("\n".join(lines) + "\n")
    return "\n".join(blocks)


def assert_bad_file_named(
    path: Path, text: str, read: Callable[[Path], object], error: type[Exception], match: str
) -> None:
    """Write ``text`` to ``path``: ``read(path)`` raises ``error`` matching ``match`` and
    naming the file."""
    import pytest

    path.write_text(text)
    with pytest.raises(error, match=match) as info:
        read(path)
    assert str(path) in str(info.value)


class LoopbackCluster:
    """A real Dask cluster on 127.0.0.1 for a test: ``dask scheduler`` and ``workers`` ×
    ``dask worker --nworkers 1 --nthreads 1`` as subprocesses (the ``dask`` next to the test's
    Python), each in its own session so that a test can kill one with :meth:`kill_worker`.

    Use as a context manager; :attr:`address` is the scheduler's ``tcp://`` address.
    """

    def __init__(self, folder: Path, workers: int = 2, timeout_s: float = 60.0) -> None:
        self.folder = Path(folder)
        self.n_workers = workers
        self.timeout_s = timeout_s
        self.procs: list = []
        self.workers: list = []
        self.address = ""

    def _start(self, *args: str):
        import os
        import subprocess
        import sys

        exe = Path(sys.executable).with_name("dask")
        root = Path(__file__).resolve().parents[1]  # this checkout's packages for the workers
        env = {
            **os.environ,
            "PYTHONPATH": os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")]),
        }
        log = open(self.folder / f"dask-{len(self.procs)}.log", "wb")
        p = subprocess.Popen(
            [str(exe), *args],
            cwd=root,
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        self.procs.append(p)
        return p

    def __enter__(self) -> LoopbackCluster:
        import json
        import time

        from distributed import Client

        sfile = self.folder / "scheduler.json"
        self._start(
            "scheduler",
            "--host",
            "127.0.0.1",
            "--port",
            "0",
            "--no-dashboard",
            "--scheduler-file",
            str(sfile),
        )
        t0 = time.monotonic()
        while not sfile.is_file() or not sfile.read_text().strip():
            if time.monotonic() - t0 > self.timeout_s:
                self.__exit__()
                raise RuntimeError("the test's Dask scheduler did not start")
            time.sleep(0.1)
        time.sleep(0.2)
        self.address = json.loads(sfile.read_text())["address"]
        for _ in range(self.n_workers):
            self.workers.append(
                self._start(
                    "worker",
                    "--scheduler-file",
                    str(sfile),
                    "--nworkers",
                    "1",
                    "--nthreads",
                    "1",
                    "--no-dashboard",
                    "--host",
                    "127.0.0.1",
                )
            )
        with Client(self.address, timeout=self.timeout_s) as client:
            client.wait_for_workers(self.n_workers, timeout=self.timeout_s)
        return self

    def kill_worker(self, i: int = 0) -> None:
        """Kill worker process ``i`` (and its nanny) at once, as a crash would."""
        import os
        import signal

        os.killpg(self.workers[i].pid, signal.SIGKILL)
        self.workers[i].wait()

    @contextlib.contextmanager
    def killing_worker_when(
        self, ready: Callable[[], bool], timeout_s: float = 60.0, poll_s: float = 0.05
    ) -> Iterator[None]:
        """Within the block, kill worker 0 from a thread as soon as ``ready()`` is true (at
        the latest after ``timeout_s``), polling every ``poll_s``; leaving the block waits for
        that thread."""

        def kill() -> None:
            t0 = time.monotonic()
            while not ready() and time.monotonic() - t0 < timeout_s:
                time.sleep(poll_s)
            self.kill_worker(0)

        killer = threading.Thread(target=kill)
        killer.start()
        try:
            yield
        finally:
            killer.join()

    def __exit__(self, *exc) -> None:
        import os
        import signal

        for p in reversed(self.procs):
            if p.poll() is None:
                try:
                    os.killpg(p.pid, signal.SIGTERM)
                except ProcessLookupError:
                    pass
        for p in reversed(self.procs):
            try:
                p.wait(timeout=20)
            except Exception:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
