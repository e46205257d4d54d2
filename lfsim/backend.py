"""Explicit initialisation of the Dr.Jit / Mitsuba backend (docs/conventions.md).

Nothing in this project sets a Mitsuba variant at import time. Every entry point that needs
Dr.Jit arrays calls :func:`init_backend` first; it is idempotent and cheap after the first call.

The LLVM (CPU) backend needs libLLVM >= 16: with LLVM 15, which Debian often installs and which
Dr.Jit finds first, Mitsuba's optics kernels abort the process with
``LLVM ERROR: Cannot select ... fminimum/fmaximum``. :func:`find_libllvm` therefore looks for a
newer library and exports ``DRJIT_LIBLLVM_PATH`` before the variant is set.
"""

from __future__ import annotations

import glob
import logging
import os
import re
from dataclasses import dataclass
from pathlib import Path

from hrvbase.errors import InputError
from hrvbase.threads import env_threads

from .errors import BackendError

log = logging.getLogger(__name__)

MIN_LLVM_MAJOR = 16

_LLVM_PATTERNS = (
    "/usr/lib/llvm-*/lib/libLLVM*.so*",
    "/usr/lib/*-linux-gnu/libLLVM*.so*",
    "/usr/lib64/libLLVM*.so*",
    "/usr/local/lib/libLLVM*.so*",
    "/opt/homebrew/opt/llvm/lib/libLLVM*.dylib",
    "/usr/local/opt/llvm/lib/libLLVM*.dylib",
)


@dataclass(frozen=True)
class BackendInfo:
    """What :func:`init_backend` chose.

    Attributes
    ----------
    variant : str
        The Mitsuba variant in use (``cuda_ad_mono`` or ``llvm_ad_mono``).
    device : str
        ``"cuda"`` or ``"llvm"``.
    threads : int
        Dr.Jit worker thread count (CPU backend).
    libllvm : str or None
        Path of the libLLVM the CPU backend loaded, ``None`` on CUDA.
    """

    variant: str
    device: str
    threads: int
    libllvm: str | None


_STATE: BackendInfo | None = None


def _llvm_major(path: str) -> int | None:
    name = os.path.basename(path)
    m = (
        re.search(r"libLLVM-(\d+)", name)
        or re.search(r"libLLVM\.so\.(\d+)", name)
        or re.search(r"llvm-(\d+)", path)
    )
    return int(m.group(1)) if m else None


def find_libllvm(min_major: int = MIN_LLVM_MAJOR) -> str:
    """Return the path of the newest libLLVM with major version >= ``min_major``.

    ``DRJIT_LIBLLVM_PATH``, when set, wins and is checked.

    Raises
    ------
    BackendError
        When no suitable library exists, with the command that installs one.
    """
    env = os.environ.get("DRJIT_LIBLLVM_PATH")
    if env:
        if not os.path.exists(env):
            raise BackendError(f"DRJIT_LIBLLVM_PATH={env!r} does not exist")
        major = _llvm_major(env)
        if major is not None and major < min_major:
            raise BackendError(
                f"DRJIT_LIBLLVM_PATH={env!r} is LLVM {major}; Mitsuba's optics kernels need "
                f"LLVM >= {min_major} (install Debian's libllvm19 and point the variable at it)"
            )
        return env
    found: list[tuple[int, str]] = []
    for pattern in _LLVM_PATTERNS:
        for path in glob.glob(pattern):
            major = _llvm_major(path)
            if major is not None and major >= min_major:
                found.append((major, path))
    if not found:
        raise BackendError(
            f"no libLLVM >= {min_major} found (looked in {', '.join(_LLVM_PATTERNS)}). "
            "Dr.Jit's CPU backend needs it: run `apt-get install libllvm19` (Debian/Ubuntu) "
            "or set DRJIT_LIBLLVM_PATH to a libLLVM >= 16."
        )
    # Newest major first; among equals prefer the shortest (unversioned-suffix) name.
    found.sort(key=lambda t: (-t[0], len(t[1])))
    return found[0][1]


def _cuda_available() -> bool:
    if os.environ.get("HRVPTM_DISABLE_CUDA"):
        return False
    for pattern in (
        "/usr/lib/*-linux-gnu/libcuda.so*",
        "/usr/lib64/libcuda.so*",
        "/usr/lib/wsl/lib/libcuda.so*",
    ):
        if glob.glob(pattern):
            return True
    return False


def init_backend(
    device: str = "auto",
    threads: int | None = None,
    cache_dir: str | os.PathLike | None = None,
) -> BackendInfo:
    """Choose and set the Mitsuba variant, thread count and kernel cache.

    Parameters
    ----------
    device : {"auto", "llvm", "cuda"}
        ``"auto"`` picks CUDA when a driver is present, else the LLVM CPU backend.
        The environment variable ``HRVPTM_DEVICE`` overrides ``"auto"``.
    threads : int, optional
        Worker threads of the CPU backend (default: all cores, or ``HRVPTM_THREADS``).
        Photon counting is integer, so images are bit-identical whatever this is.
    cache_dir : path, optional
        Where Dr.Jit keeps compiled kernels (default ``~/.drjit``; ``HRVPTM_KERNEL_CACHE``).

    Returns
    -------
    BackendInfo

    Raises
    ------
    BackendError
        Unknown device, CUDA asked for but absent, or no usable libLLVM.
    """
    global _STATE
    if device == "auto":
        device = os.environ.get("HRVPTM_DEVICE", "auto")
    if device not in ("auto", "llvm", "cuda"):
        raise BackendError(f"device must be 'auto', 'llvm' or 'cuda', got {device!r}")
    if threads is None:
        try:
            threads = env_threads()
        except InputError as exc:
            raise BackendError(str(exc)) from None
    if threads is not None and threads < 1:
        raise BackendError(f"threads must be >= 1, got {threads}")
    cache_dir = cache_dir or os.environ.get("HRVPTM_KERNEL_CACHE")
    if device == "cuda" and not _cuda_available():
        raise BackendError(
            "device 'cuda': no CUDA driver on this machine (no libcuda found, or "
            "HRVPTM_DISABLE_CUDA is set); use device 'auto' or 'llvm' to run on the CPU"
        )

    if _STATE is not None:
        if device not in ("auto", _STATE.device):
            raise BackendError(
                f"backend already initialised as {_STATE.variant}; cannot switch to {device} "
                "in the same process"
            )
        if threads is not None and threads != _STATE.threads:
            import drjit as dr

            dr.set_thread_count(threads)
            _STATE = BackendInfo(_STATE.variant, _STATE.device, threads, _STATE.libllvm)
        return _STATE

    if cache_dir is not None:
        Path(cache_dir).mkdir(parents=True, exist_ok=True)
        # Dr.Jit stores its kernel cache under $HOME/.drjit.
        os.environ["DRJIT_CACHE_DIR"] = str(cache_dir)

    libllvm = None
    auto = device == "auto"
    if auto:
        device = "cuda" if _cuda_available() else "llvm"

    import drjit as dr
    import mitsuba as mi

    if device == "cuda":
        try:
            mi.set_variant("cuda_ad_mono")
        except (ImportError, AttributeError, RuntimeError) as exc:  # pragma: no cover - GPU
            if not auto:
                raise BackendError(
                    "device 'cuda': the CUDA driver is installed but Dr.Jit could not start "
                    "on a GPU (none usable?); use device 'auto' or 'llvm' to run on the CPU "
                    f"(Dr.Jit said: {exc})"
                ) from exc
            # A CUDA driver library without a usable GPU: fall back to the CPU.
            log.warning("CUDA backend unavailable (%s); using the LLVM CPU backend", exc)
            device = "llvm"
    if device == "llvm":
        libllvm = find_libllvm()
        os.environ["DRJIT_LIBLLVM_PATH"] = libllvm
        try:
            mi.set_variant("llvm_ad_mono")
        except (ImportError, AttributeError, RuntimeError) as exc:  # pragma: no cover
            raise BackendError(f"cannot set Mitsuba variant 'llvm_ad_mono': {exc}") from exc
    variant = f"{device}_ad_mono"
    if device == "llvm":
        if threads is not None:
            dr.set_thread_count(threads)
        threads = dr.thread_count()
    else:
        threads = threads or 1

    from .plugins import register_plugins

    register_plugins()
    _STATE = BackendInfo(variant=variant, device=device, threads=int(threads), libllvm=libllvm)
    log.info("backend %s, %d threads, libLLVM %s", variant, threads, libllvm)
    return _STATE


def backend_info() -> BackendInfo | None:
    """The current backend, or ``None`` before :func:`init_backend`."""
    return _STATE
