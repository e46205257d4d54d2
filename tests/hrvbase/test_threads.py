"""One reading of HRVPTM_THREADS for every package (hrvbase.threads)."""

from __future__ import annotations

import pytest

from hrvbase.errors import InputError
from hrvbase.threads import available_cores, compute_threads, env_threads


def test_unset_means_every_core(monkeypatch):
    monkeypatch.delenv("HRVPTM_THREADS", raising=False)
    assert env_threads() is None and compute_threads() == available_cores() >= 1
    monkeypatch.setenv("HRVPTM_THREADS", " ")
    assert env_threads() is None


def test_set_caps_the_threads(monkeypatch):
    monkeypatch.setenv("HRVPTM_THREADS", "3")
    assert env_threads() == 3 and compute_threads() == 3


@pytest.mark.parametrize("bad", ["0", "-2", "two", "1.5"])
def test_bad_values_are_one_line_errors_in_every_package(monkeypatch, bad):
    monkeypatch.setenv("HRVPTM_THREADS", bad)
    msg = f"environment variable HRVPTM_THREADS must be an integer >= 1, got {bad!r}"
    with pytest.raises(InputError, match=msg):
        env_threads()
    from recon.errors import InputError as ReconInputError
    from recon.projector import resolve_threads
    from track._threads import compute_threads as track_threads
    from track.errors import InputError as TrackInputError

    with pytest.raises(ReconInputError, match=msg):
        resolve_threads()
    with pytest.raises(TrackInputError, match=msg):
        track_threads()


def test_one_blas_thread_limits_numpy_and_scipy_blas_and_nests():
    import scipy.linalg  # noqa: F401
    from threadpoolctl import threadpool_info

    from hrvbase.threads import one_blas_thread

    def blas_threads():
        info = threadpool_info()
        return {i["filepath"]: i["num_threads"] for i in info if i["user_api"] == "blas"}

    before = blas_threads()
    with one_blas_thread():
        inside = blas_threads()
        assert inside.keys() == before.keys() and set(inside.values()) == {1}
        with one_blas_thread():  # nested: nothing changes, before or after
            assert blas_threads() == inside
        assert blas_threads() == inside
        with one_blas_thread():  # the depth came back: a second nested block too
            assert blas_threads() == inside
    assert blas_threads() == before  # set back
