"""The bad-input corpus of the frames-in-parallel options, ``--workers`` and ``--scheduler``, in
every command that takes them (``lfsim dataset``, ``recon run``, ``track run|detect|link``,
``hrvptm study|demo``): each is refused in one line naming the option, before any work.

A scheduler address answered by something else is served by the case itself: a plain TCP
service on a free port of 127.0.0.1 (an HTTP or SSH greeting, silence, or a connection closed at
once) that stops by itself after :data:`SERVICE_S` seconds; nothing listens on a closed port.
Every connection attempt is bounded by :data:`hrvbase.parallel.CONNECT_TIMEOUT_S`.
"""

from __future__ import annotations

import socket
import threading
import time
from pathlib import Path

import pytest

from tests.corpus import FAST, Base, Case, Env, case_adder, params, run_case

CASES: list[Case] = []
case = case_adder(CASES)

#: Seconds a case's service listens (far longer than a case).
SERVICE_S = 30.0


def closed_port() -> str:
    """A ``tcp://`` address on 127.0.0.1 on which nothing listens."""
    with socket.create_server(("127.0.0.1", 0)) as s:
        port = s.getsockname()[1]
    return f"tcp://127.0.0.1:{port}"


def service(reply: bytes | None, *, hang_up: bool = False) -> str:
    """Start a TCP service that is not a Dask scheduler; its ``tcp://`` address.

    It answers each connection with ``reply`` (``None``: says nothing) and keeps it open, or
    closes it at once (``hang_up``); it stops after :data:`SERVICE_S` seconds.
    """
    sock = socket.create_server(("127.0.0.1", 0))
    sock.settimeout(0.2)
    port = sock.getsockname()[1]

    def serve() -> None:
        conns = []
        t0 = time.monotonic()
        with sock:
            while time.monotonic() - t0 < SERVICE_S:
                try:
                    conn, _ = sock.accept()
                except TimeoutError:
                    continue
                try:
                    if reply is not None:
                        conn.sendall(reply)
                except OSError:
                    pass
                if hang_up:
                    conn.close()
                else:
                    conns.append(conn)
        for conn in conns:
            conn.close()

    threading.Thread(target=serve, daemon=True).start()
    return f"tcp://127.0.0.1:{port}"


HTTP = b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\nConnection: close\r\n\r\n"
SSH = b"SSH-2.0-OpenSSH_9.6p1 Ubuntu-3ubuntu13\r\n"


# -- argv of each command ---------------------------------------------------------------------
def recon_run(e: Env, *extra) -> list:
    return ["run", e.b.ds, *FAST, "--iterations", "1", *extra, "-o", e.o("v")]


def track_cmd(cmd: str):
    def argv(e: Env, *extra) -> list:
        if cmd == "link":
            return ["link", *e.b.clouds, "-o", e.o("res"), *extra]
        return [cmd, e.b.vol, "-o", e.o("res"), *extra]

    return argv


def lfsim_dataset(e: Env, *extra) -> list:
    return ["dataset", e.b.exp, "-o", e.o("ds"), *extra]


def hrvptm_study(e: Env, *extra) -> list:
    return ["study", e.b.study, "-o", e.o("rep"), *extra]


def hrvptm_demo(e: Env, *extra) -> list:
    return ["demo", "-o", e.o("demo"), *extra]


COMMANDS = {
    ("recon", "recon-run"): recon_run,
    ("track", "track-run"): track_cmd("run"),
    ("track", "track-detect"): track_cmd("detect"),
    ("track", "track-link"): track_cmd("link"),
    ("lfsim", "lfsim-dataset"): lfsim_dataset,
    ("hrvptm", "hrvptm-study"): hrvptm_study,
    ("hrvptm", "hrvptm-demo"): hrvptm_demo,
}


def add(prefix: str, cid: str, extra, needle: str, **kw) -> None:
    """A case of the command ``prefix`` (``"recon-run"``) with the options ``extra`` (a list,
    or a function of the case's :class:`Env` giving it)."""
    (prog, _), make = next((k, v) for k, v in COMMANDS.items() if k[1] == prefix)

    def argv(e: Env, make=make, extra=extra) -> list:
        return make(e, *(extra(e) if callable(extra) else extra))

    case(f"{prefix}-{cid}", prog, argv, needle, **kw)


WORKERS = "--workers must be an integer >= 1 or 'auto'"
PORT = "the port must be an integer in 1..65535"
NO_PORT = "the port is missing"
NOT_DASK = "not a Dask scheduler"
NOTHING = "nothing is listening"
BOTH = "--workers and --scheduler exclude each other"

# ---- --workers: not a count of processes ----
for prefix, cid, value in [
    ("recon-run", "zero", "0"),
    ("recon-run", "negative", "-1"),
    ("recon-run", "text", "many"),
    ("recon-run", "float", "2.5"),
    ("recon-run", "exponent", "1e9"),
    ("recon-run", "hex", "0x2"),
    ("track-run", "zero", "0"),
    ("track-run", "text", "all"),
    ("track-detect", "negative", "-4"),
    ("track-link", "float", "1.5"),
    ("lfsim-dataset", "zero", "0"),
    ("lfsim-dataset", "float", "0.5"),
    ("hrvptm-study", "zero", "0"),
    ("hrvptm-study", "text", "two"),
    ("hrvptm-demo", "negative", "-3"),
]:
    add(prefix, f"workers-{cid}", [f"--workers={value}"], f"{WORKERS}, got {value!r}")

# ---- --workers beyond the machine: capped with a warning (two clouds: one pair, linked and
# gridded in this process, so no cluster is started and the case takes seconds) ----
case(
    "track-link-workers-beyond-the-machine",
    "track",
    lambda e: ["link", *e.b.clouds[:2], "-o", e.o("res"), "--workers", "1000000000"],
    "--workers 1000000000: using ",
    kind="warning",
    writes=True,
)

# ---- --scheduler: not an address of a Dask scheduler (its form) ----
for prefix, cid, address, needle in [
    ("recon-run", "no-port", "banana", NO_PORT),
    ("recon-run", "port-zero", "tcp://127.0.0.1:0", PORT),
    ("recon-run", "port-too-big", "tcp://127.0.0.1:70000", PORT),
    ("recon-run", "port-text", "tcp://127.0.0.1:dask", PORT),
    ("recon-run", "unknown-scheme", "http://127.0.0.1:8786", "unknown scheme 'http'"),
    ("recon-run", "empty", "", "--scheduler must be an address"),
    ("track-run", "no-host", "tcp://:8786", "the host is missing"),
    ("track-run", "with-path", "tcp://127.0.0.1:8786/status", "expected tcp://HOST:PORT"),
    ("track-detect", "ipv6-no-port", "tcp://[::1]", NO_PORT),
    ("track-link", "blank", "   ", "--scheduler must be an address"),
    ("lfsim-dataset", "no-port", "tcp://127.0.0.1", NO_PORT),
    ("lfsim-dataset", "port-negative", "tcp://127.0.0.1:-1", PORT),
    ("hrvptm-study", "unknown-scheme", "udp://127.0.0.1:8786", "unknown scheme 'udp'"),
    ("hrvptm-demo", "two-ports", "tcp://127.0.0.1:8786:8787", "expected tcp://HOST:PORT"),
]:
    add(prefix, f"scheduler-{cid}", ["--scheduler", address], needle)

# ---- --scheduler: nothing there, or something else than Dask (fails within seconds) ----
for prefix, cid, address, needle in [
    ("recon-run", "closed-port", lambda: closed_port(), NOTHING),
    ("recon-run", "http-service", lambda: service(HTTP), NOT_DASK),
    ("track-run", "closed-port", lambda: closed_port(), NOTHING),
    ("track-run", "ssh-service", lambda: service(SSH), NOT_DASK),
    ("track-detect", "silent-service", lambda: service(None), "no answer within"),
    ("track-link", "hang-up-service", lambda: service(None, hang_up=True), NOT_DASK),
    ("lfsim-dataset", "closed-port", lambda: closed_port(), NOTHING),
    ("lfsim-dataset", "http-service", lambda: service(HTTP), NOT_DASK),
    ("hrvptm-study", "closed-port", lambda: closed_port(), NOTHING),
    ("hrvptm-demo", "ssh-service", lambda: service(SSH), NOT_DASK),
]:
    add(prefix, f"scheduler-{cid}", lambda e, a=address: ["--scheduler", a()], needle)

# ---- --workers with --scheduler: contradictory ----
for prefix in ("recon-run", "track-run", "lfsim-dataset", "hrvptm-study"):
    add(prefix, "workers-with-scheduler", ["--workers", "2", "--scheduler", "tcp://h:8786"], BOTH)


@pytest.mark.parametrize("c", params(CASES))
def test_bad_input(c: Case, corpus_base: Base, tmp_path: Path, capsys) -> None:
    run_case(c, corpus_base, tmp_path, capsys)


def test_cases_are_distinct_and_cover_every_command() -> None:
    from tests.test_bad_inputs import CASES as MAIN

    ids = [c.id for c in CASES]
    assert len(ids) >= 25 and len(set(ids)) == len(ids)
    assert not set(ids) & {c.id for c in MAIN}
    for _, prefix in COMMANDS:
        assert any(i.startswith(f"{prefix}-workers-") for i in ids), prefix
        assert any(i.startswith(f"{prefix}-scheduler-") for i in ids), prefix
