"""Backend initialisation: libLLVM discovery and the explicit variant choice."""

from __future__ import annotations

import pytest

from lfsim import BackendError, find_libllvm
from lfsim.backend import _llvm_major, init_backend


def test_llvm_version_parsing():
    assert _llvm_major("/usr/lib/x86_64-linux-gnu/libLLVM-19.so") == 19
    assert _llvm_major("/usr/lib/x86_64-linux-gnu/libLLVM.so.15.0") == 15
    assert _llvm_major("/usr/lib/llvm-17/lib/libLLVM.so") == 17


def test_finds_new_enough_libllvm(monkeypatch):
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
    path = find_libllvm()
    assert _llvm_major(path) >= 16


def test_old_llvm_rejected_with_clear_message(monkeypatch, tmp_path):
    fake = tmp_path / "libLLVM-15.so"
    fake.write_bytes(b"")
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", str(fake))
    with pytest.raises(BackendError, match="LLVM 15"):
        find_libllvm()
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", str(tmp_path / "missing.so"))
    with pytest.raises(BackendError, match="does not exist"):
        find_libllvm()


def test_none_found_names_the_fix(monkeypatch):
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
    monkeypatch.setattr("lfsim.backend._LLVM_PATTERNS", ("/nonexistent/libLLVM*.so",))
    with pytest.raises(BackendError, match="libllvm19"):
        find_libllvm()


def test_import_sets_no_variant():
    import subprocess
    import sys

    code = "import lfsim, mitsuba as mi; print(mi.variant())"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "None"


def test_backend_is_llvm_mono_on_cpu(backend):
    assert backend.variant in ("llvm_ad_mono", "cuda_ad_mono")
    assert init_backend() is backend or init_backend().variant == backend.variant
    with pytest.raises(BackendError, match="device"):
        init_backend(device="opencl")
    with pytest.raises(BackendError, match="threads"):
        init_backend(threads=0)
