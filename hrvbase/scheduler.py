"""Existing Dask schedulers: their addresses (:func:`scheduler_address`), a connection check
that names what is wrong in one line (:func:`check_scheduler`) and a client of one
(:func:`_open_client`), for :mod:`hrvbase.parallel`'s ``Parallel(scheduler=...)``."""

from __future__ import annotations

import logging
import re
import socket
import struct

from .errors import InputError

log = logging.getLogger(__name__)


#: Seconds to wait for an existing scheduler to answer (to accept the connection, to greet,
#: and for the client to connect).
CONNECT_TIMEOUT_S = 5.0


#: Schemes of a scheduler address (Dask's TCP and TLS transports).
SCHEDULER_SCHEMES = ("tcp", "tls")


_EXPECTED_ADDRESS = "expected tcp://HOST:PORT or tls://HOST:PORT (e.g. tcp://10.0.0.5:8786)"


#: ``[scheme://]host[:port]``, the host a name, an IPv4 address or a bracketed IPv6 address.
_ADDRESS = re.compile(
    r"(?:(?P<scheme>[^:/]*)://)?(?P<host>\[[^\]/]*\]|[^:/\[\]]*)(?::(?P<port>[^:/]*))?"
)


#: A Dask scheduler greets each connection with a short message whose first 8 bytes are its
#: length (``distributed.comm.tcp``); a longer "greeting" is another service's bytes.
_MAX_GREETING_BYTES = 1 << 20


def scheduler_address(text: str, name: str = "scheduler") -> tuple[str, str, int]:
    """The scheme, host and port of a Dask scheduler address, checked without connecting.

    Parameters
    ----------
    text : str
        ``tcp://HOST:PORT`` or ``tls://HOST:PORT`` (``HOST:PORT``: TCP, as in Dask); the host a
        name, an IPv4 address or an IPv6 address in brackets.
    name : str
        What the messages call it (``"--scheduler"`` on a command line).

    Returns
    -------
    tuple of (str, str, int)
        Scheme (lower case), host (without brackets) and port (1..65535).

    Raises
    ------
    InputError
        Any other form: the message names ``text`` and what is missing or wrong.
    """
    m = _ADDRESS.fullmatch(text.strip())
    if m is None:
        raise InputError(f"{name} {text}: {_EXPECTED_ADDRESS}")
    scheme = "tcp" if m["scheme"] is None else m["scheme"].lower()
    if scheme not in SCHEDULER_SCHEMES:
        raise InputError(f"{name} {text}: unknown scheme {scheme!r}; {_EXPECTED_ADDRESS}")
    host = m["host"].strip("[]")
    if not host:
        raise InputError(f"{name} {text}: the host is missing; {_EXPECTED_ADDRESS}")
    port = m["port"]
    if port is None:
        raise InputError(f"{name} {text}: the port is missing; {_EXPECTED_ADDRESS}")
    if not (port.isascii() and port.isdigit() and 1 <= int(port) <= 65535):
        raise InputError(f"{name} {text}: the port must be an integer in 1..65535, got {port!r}")
    return scheme, host, int(port)


def _recv_exactly(sock: socket.socket, n: int) -> bytes:
    """Up to ``n`` bytes from ``sock`` (fewer: the peer closed the connection)."""
    data = b""
    while len(data) < n:
        chunk = sock.recv(n - len(data))
        if not chunk:
            break
        data += chunk
    return data


def check_scheduler(address: str, name: str = "scheduler", timeout: float | None = None) -> None:
    """Check that a Dask scheduler answers at ``address``, within ``timeout`` seconds.

    The connection is made with a plain socket: the address must accept it and (``tcp``)
    greet as a Dask scheduler does, with the length of a short message. Nothing else is read
    (another service's bytes are never taken for a length to allocate), and the socket is
    closed before returning.

    Parameters
    ----------
    address : str
        Scheduler address (:func:`scheduler_address`).
    name : str
        What the messages call it (``"--scheduler"`` on a command line).
    timeout : float, optional
        Seconds for the connection and for the greeting (default :data:`CONNECT_TIMEOUT_S`).

    Raises
    ------
    InputError
        A malformed address, an unknown host, nothing listening, no answer in time, or a
        service that is not a Dask scheduler; one line naming the address.
    """
    scheme, host, port = scheduler_address(address, name)
    t = CONNECT_TIMEOUT_S if timeout is None else timeout
    where = f"{name} {address}"
    try:
        sock = socket.create_connection((host, port), timeout=t)
    except ConnectionRefusedError:
        raise InputError(
            f"{where}: nothing is listening there (connection refused); is the scheduler "
            "running (`dask scheduler`)?"
        ) from None
    except TimeoutError:
        raise InputError(f"{where}: no answer within {t:g} s") from None
    except socket.gaierror as exc:
        raise InputError(f"{where}: unknown host {host!r} ({exc.strerror})") from None
    except OSError as exc:
        raise InputError(f"{where}: cannot connect ({' '.join(str(exc).split())})") from None
    with sock:
        if scheme != "tcp":  # TLS: the greeting comes after the TLS handshake
            return
        try:
            head = _recv_exactly(sock, 8)
        except TimeoutError:
            raise InputError(
                f"{where}: no answer within {t:g} s (a Dask scheduler greets each "
                "connection); is it a Dask scheduler?"
            ) from None
        except OSError as exc:
            raise InputError(
                f"{where}: the connection failed ({' '.join(str(exc).split())})"
            ) from None
    if len(head) < 8:
        raise InputError(f"{where}: closed the connection without greeting: not a Dask scheduler")
    (length,) = struct.unpack("Q", head)
    if length > _MAX_GREETING_BYTES:
        raise InputError(f"{where}: not a Dask scheduler (it answered {head!r})")


def _close_half_built_client(exc: BaseException) -> None:
    """Close the :class:`distributed.Client` whose constructor raised ``exc``.

    A client that failed to connect is otherwise closed by its finalizer, which then waits for
    its event loop (20 s) and prints a traceback."""
    from distributed import Client

    clients = []
    tb = exc.__traceback__
    while tb is not None:
        candidate = tb.tb_frame.f_locals.get("self")
        if isinstance(candidate, Client) and candidate not in clients:
            clients.append(candidate)
        tb = tb.tb_next
    for client in clients:
        try:
            client.close(timeout=2)
        except Exception as err:  # best effort: it never connected
            log.debug("closing a Dask client that failed to connect: %s", err)


def _open_client(address: str, name: str = "--scheduler"):
    """A :class:`distributed.Client` of the scheduler at ``address`` (checked first with
    :func:`check_scheduler`); InputError, in one line, when it cannot connect."""
    import dask
    from distributed import Client

    check_scheduler(address, name)
    try:
        with dask.config.set({"distributed.comm.timeouts.connect": CONNECT_TIMEOUT_S}):
            return Client(address, timeout=CONNECT_TIMEOUT_S, set_as_default=False)
    except Exception as exc:  # it answered the probe but not the client
        _close_half_built_client(exc)
        message = " ".join(str(exc).split())
        raise InputError(
            f"{name} {address}: cannot connect to a Dask scheduler there within "
            f"{CONNECT_TIMEOUT_S:g} s ({type(exc).__name__}: {message})"
        ) from None


__all__ = ["CONNECT_TIMEOUT_S", "SCHEDULER_SCHEMES", "check_scheduler", "scheduler_address"]
