"""Forward and backward projection: exact adjoint, flux, agreement with the simulator."""

from __future__ import annotations

import numpy as np
import pytest

from recon.errors import InputError

#: <Hx, y> = <x, Hᵀy> for random float32 fields: H and Hᵀ sum the same float32 products in
#: different orders, so they agree to float32 accumulation round-off (measured 0.7–1.4e-8 for
#: the gather projector, ≤ 5.5e-9 for the sparse one), below one float32 ulp (6e-8).
ADJOINT_RTOL = 5e-8


def assert_adjoint(p, x, y) -> float:
    """``<H x, y> = <x, Hᵀ y>`` to :data:`ADJOINT_RTOL` for the projector ``p``; returns the
    left-hand side."""
    lhs = np.dot(p.forward(x).ravel().astype(np.float64), y.ravel())
    rhs = np.dot(x.ravel().astype(np.float64), p.backward(y).ravel())
    assert abs(lhs - rhs) <= ADJOINT_RTOL * abs(lhs)
    return lhs


def assert_adjoint_on_random_fields(p, rng, trials: int) -> None:
    """:func:`assert_adjoint` for ``trials`` pairs of random float32 fields."""
    for _ in range(trials):
        x = rng.random(p.volume_shape).astype(np.float32)
        y = rng.random(p.image_shape).astype(np.float32)
        assert_adjoint(p, x, y)


def test_adjoint_dot_product(small_projector, rng):
    assert_adjoint_on_random_fields(small_projector, rng, 3)


def test_adjoint_is_the_exact_transpose_element_by_element(small_projector, rng):
    """H[p, v] (pixel p of the image of voxel v) equals Hᵀ[v, p] (voxel v of the back-projection
    of pixel p) to 1e-9: one float32 weight on both sides, no accumulation (measured: equal)."""
    p = small_projector
    pairs = 0
    for _ in range(10):
        v = tuple(int(rng.integers(0, s)) for s in p.volume_shape)
        e = np.zeros(p.volume_shape, np.float32)
        e[v] = 1.0
        col = p.forward(e).ravel()
        support = np.flatnonzero(col > 0)
        assert support.size > 0
        for q in rng.choice(support, size=min(3, support.size), replace=False):
            ep = np.zeros(p.image_shape, np.float32)
            ep.ravel()[q] = 1.0
            assert p.backward(ep)[v] == pytest.approx(col[q], rel=1e-9, abs=0)
            pairs += 1
    assert pairs >= 20


def test_adjoint_on_sparse_vectors(small_projector, rng):
    """Single voxels against single pixels catch index bugs that random fields average out."""
    p = small_projector
    x = np.zeros(p.volume_shape, np.float32)
    idx = [tuple(rng.integers(0, s) for s in p.volume_shape) for _ in range(20)]
    for i in idx:
        x[i] = rng.random() + 0.5
    hx = p.forward(x)
    y = (hx > 0).astype(np.float32) * rng.random(p.image_shape).astype(np.float32)
    assert assert_adjoint(p, x, y) > 0


def test_flux_conservation(small_projector, small_bank):
    """An interior voxel's light all lands in the image; Hᵀ1 of it is its pattern sum."""
    p = small_projector
    x = np.zeros(p.volume_shape, np.float32)
    k = 20
    x[k, 31, 31] = 2.5  # lenslet (10, 10), centre sub-position
    c = k * 9 + 4
    pattern_sum = float(small_bank.w[small_bank.offsets[c] : small_bank.offsets[c + 1]].sum())
    assert p.forward(x).sum() == pytest.approx(2.5 * pattern_sum, rel=1e-6)
    ht1 = p.backward(np.ones(p.image_shape, np.float32))
    assert ht1[k, 31, 31] == pytest.approx(pattern_sum, rel=1e-6)
    # Edge voxels lose the light that falls off the sensor: Hᵀ1 < pattern sum there.
    assert ht1[-1, 0, 0] < 0.9 * ht1[-1, 31, 31]


def test_forward_of_voxel_matches_simulated_point(small_projector, small_optics_, small_grid):
    from lfsim.tracer import RenderSettings, Sources, trace_paraxial

    p = small_projector
    k, j, i = 35, 25, 40  # z = 270 µm, an off-axis voxel
    x = np.zeros(p.volume_shape, np.float32)
    x[k, j, i] = 1.0
    pos = small_grid.to_um(np.array([[k, j, i]], float))[0]

    def traced(n_rays, seed):
        settings = RenderSettings(rays_per_particle=n_rays, mode="expected", seed=seed)
        return trace_paraxial(small_optics_, Sources.spheres([pos], 0.0), settings) / n_rays

    ref = traced(400_000, 3)
    noise = np.abs(traced(50_000, 4) - ref).sum()  # the bank's own Monte Carlo noise level
    img = p.forward(x)
    assert np.abs(img - ref).sum() < 1.2 * noise + 0.01
    assert np.abs(np.roll(img, 15, axis=1) - ref).sum() > 1.0  # one lenslet off: caught


def test_shape_errors(small_projector):
    with pytest.raises(InputError, match="volume shape"):
        small_projector.forward(np.zeros((2, 3, 4), np.float32))
    with pytest.raises(InputError, match="image shape"):
        small_projector.backward(np.zeros((3, 4), np.float32))


def test_sparse_projector_is_the_same_operator(small_bank, small_projector, rng):
    from recon.projector import LightFieldProjector, SparseProjector, make_projector

    sp = SparseProjector(small_bank, (20, 20), block_mb=0.5)  # force several blocks per depth
    assert len(sp._blocks) > small_bank.depths_um.size
    x = rng.random(sp.volume_shape).astype(np.float32)
    y = rng.random(sp.image_shape).astype(np.float32)
    hx, hty = small_projector.forward(x), small_projector.backward(y)
    np.testing.assert_allclose(sp.forward(x), hx, rtol=0, atol=1e-5 * hx.max())
    np.testing.assert_allclose(sp.backward(y), hty, rtol=0, atol=1e-5 * hty.max())
    assert_adjoint(sp, x, y)
    assert sp.macs_per_projection == small_projector.macs_per_projection
    from lfsim.backend import backend_info

    auto = make_projector(small_bank, (20, 20))
    # the measured winner of each backend: scipy.sparse on the CPU, the gathers on CUDA
    winner = LightFieldProjector if backend_info().device == "cuda" else SparseProjector
    assert isinstance(auto, winner)
    with pytest.raises(InputError, match="projector"):
        make_projector(small_bank, (20, 20), "fft")


@pytest.mark.parametrize("block_mb", [256.0, 0.5])
def test_sparse_projector_threads_are_bit_identical(small_bank, rng, block_mb):
    """1, 2, 3 and 16 threads (H: slabs of 20, 10, 6–7 and 1–2 lenslet rows; Hᵀ: whole
    blocks, or with 16 threads ranges of a block's channels) give the same bits: every output
    element is summed in one order."""
    from recon.projector import SparseProjector

    counts = (1, 2, 3, 16)
    ps = [SparseProjector(small_bank, (20, 20), block_mb=block_mb, threads=t) for t in counts]
    assert [p.threads for p in ps] == list(counts)
    if block_mb == 256.0:  # 49 blocks for 16 threads: Hᵀ splits blocks by channels
        assert len(ps[-1]._backward_tasks) > len(ps[-1]._blocks) == len(ps[0]._backward_tasks)
    x = rng.random(ps[0].volume_shape).astype(np.float32)
    y = rng.random(ps[0].image_shape).astype(np.float32)
    # a sparse volume too: far-off shifts landing outside the grid must be cut per slab
    xs = np.where(rng.random(x.shape) < 0.01, x, 0).astype(np.float32)
    ref_f, ref_fs, ref_b = ps[0].forward(x), ps[0].forward(xs), ps[0].backward(y)
    assert (ref_f > 0).mean() > 0.5 and (ref_b > 0).mean() > 0.5 and (ref_fs > 0).any()
    for p in ps[1:]:
        assert p.forward(x).tobytes() == ref_f.tobytes()
        assert p.forward(xs).tobytes() == ref_fs.tobytes()
        assert p.backward(y).tobytes() == ref_b.tobytes()


def test_resolve_threads(monkeypatch):
    from recon import projector
    from recon.projector import resolve_threads

    monkeypatch.delenv("HRVPTM_THREADS", raising=False)
    monkeypatch.setattr(projector, "available_cores", lambda: 8)
    assert resolve_threads() == 8
    assert resolve_threads(None, workers=3) == 2  # threads × workers ≤ cores
    assert resolve_threads(None, workers=16) == 1
    assert resolve_threads(5, workers=4) == 5  # asked for: kept
    for bad in (0, -1, 1.5, True, "2"):
        with pytest.raises(InputError, match="threads must be an integer >= 1"):
            resolve_threads(bad)
    with pytest.raises(InputError, match="workers must be an integer >= 1"):
        resolve_threads(None, workers=0)
    monkeypatch.setenv("HRVPTM_THREADS", "3")  # the Dr.Jit backend's variable, too
    assert resolve_threads() == 3 and resolve_threads(None, workers=2) == 3
    assert resolve_threads(2) == 2
    monkeypatch.setenv("HRVPTM_THREADS", "0")
    with pytest.raises(InputError, match="HRVPTM_THREADS must be an integer >= 1, got '0'"):
        resolve_threads()


def test_make_projector_passes_threads(small_bank, monkeypatch):
    from recon.projector import SparseProjector, make_projector

    p = make_projector(small_bank, (20, 20), "sparse", threads=3)
    assert isinstance(p, SparseProjector) and p.threads == 3
    from recon.projector import available_cores

    monkeypatch.delenv("HRVPTM_THREADS", raising=False)
    p = make_projector(small_bank, (20, 20), "sparse", workers=available_cores() + 1)
    assert p.threads == 1  # more frame workers than cores: one thread each
    with pytest.raises(InputError, match="threads"):
        make_projector(small_bank, (20, 20), "sparse", threads=0)


def test_work_split_covers_every_index_once():
    from recon.projector import _parts, _parts_by_weight

    assert _parts(20, 3) == [(0, 6), (6, 13), (13, 20)]
    assert _parts(2, 5) == [(0, 1), (1, 2)]
    assert _parts_by_weight(np.array([10, 1, 1, 1]), 2) == [(0, 1), (1, 4)]  # heavy first
    assert _parts_by_weight(np.array([1, 1, 1, 10]), 3) == [(0, 3), (3, 4)]
    assert _parts_by_weight(np.array([1, 2, 3, 4, 5, 6]), 4) == [(0, 3), (3, 4), (4, 5), (5, 6)]
    rng = np.random.default_rng(0)
    for _ in range(50):
        w = rng.integers(0, 100, int(rng.integers(1, 40)))
        parts = _parts_by_weight(w, int(rng.integers(1, 8)))
        assert [a for a, _ in parts][1:] == [b for _, b in parts][:-1]  # contiguous
        assert parts[0][0] == 0 and parts[-1][1] == len(w) and all(b > a for a, b in parts)
