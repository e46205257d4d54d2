"""Smoothing thin-plate splines in 3-D: the kernel, the eigen-basis of a spline with a degree-1
polynomial on a set of centres, and the smoothing parameter chosen by generalised
cross-validation (GCV).

The basis (:class:`_ThinPlateBasis`) is decomposed once per particle set; every smoothing
parameter λ reuses it: GCV's scan (:func:`gcv_smoothing`) and the fit itself
(:class:`track.thin_plate_fit._ThinPlateFit`).
"""

from __future__ import annotations

import numpy as np

from hrvbase.validate import points_xyz

from .errors import InputError

#: Fewest particles for which :func:`gcv_smoothing` chooses λ (below it: exact interpolation).
GCV_MIN_POINTS = 10


def _points(arr, name: str) -> np.ndarray:
    return points_xyz(arr, name, error=InputError)


def _tps_kernel(r: np.ndarray) -> np.ndarray:
    """``r² log r`` (0 at ``r = 0``): the kernel and sign scipy's ``thin_plate_spline`` uses."""
    from scipy.special import xlogy

    return xlogy(r * r, r)


def _tps_kernel_sq(r2: np.ndarray) -> np.ndarray:
    """:func:`_tps_kernel` from ``r²``, as ``r² log(r²) / 2`` (no square root, no ``xlogy``)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        k = np.log(r2)
        k *= r2
    k *= 0.5
    k[r2 <= 0] = 0.0
    return k


def gcv_smoothing(
    positions_um: np.ndarray,
    values: np.ndarray,
    *,
    max_points: int = 1000,
    seed: int = 0,
) -> np.ndarray:
    """Smoothing parameter of a thin-plate-spline fit chosen by generalised cross-validation.

    For each column ``y`` of ``values`` the smoothing thin-plate spline with a degree-1
    polynomial, ``f_λ = argmin Σ (y_i − f(x_i))² + λ J(f)`` (exactly what
    :class:`scipy.interpolate.RBFInterpolator` fits with ``kernel="thin_plate_spline"``,
    ``degree=1``, ``smoothing=λ``), has the influence matrix ``A(λ)`` with ``f_λ(x) = A y``.
    GCV (Craven & Wahba 1979, *Numer. Math.* 31:377) picks the λ minimising

    ``V(λ) = n ‖(I − A(λ)) y‖² / tr(I − A(λ))²``,

    an estimate of the prediction error that needs neither the truth nor the noise level.
    With ``Q₂`` an orthonormal basis of the null space of the polynomial block ``Pᵀ`` and
    ``Q₂ᵀ K Q₂ = U diag(γ) Uᵀ`` (Wahba 1990, *Spline Models for Observational Data*, §4.3),

    ``(I − A) y = Q₂ U diag(λ / (γ + λ)) Uᵀ Q₂ᵀ y``,  ``tr(I − A) = Σ λ / (γ_k + λ)``,

    so one eigen-decomposition gives ``V`` for every λ of a log-spaced scan (16 decades, 10 per
    decade). A column of exactly affine data (its non-affine part ``Bᵀ y`` at round-off,
    :data:`GCV_AFFINE_RTOL`) gets the largest λ of the scan: its fit is that affine function
    for every λ, its uncertainties those of the affine least-squares fit (round-off alone
    would otherwise choose λ, differently with each BLAS and thread count).

    Parameters
    ----------
    positions_um : ndarray, shape (N, 3)
        Particle positions (µm).
    values : ndarray, shape (N,) or (N, C)
        Data at the particles, e.g. the three displacement components (µm).
    max_points : int
        Above this many particles λ is chosen on a random subset of ``max_points`` particles
        and multiplied by ``N / max_points`` (the data term of the criterion grows with the
        particle density, the penalty does not).
    seed : int
        Seed of that subset.

    Returns
    -------
    ndarray, shape (C,)
        λ for each column (µm⁻¹ for data in µm: the units of ``J`` are µm² / µm³).

    Raises
    ------
    InputError
        Bad shapes, non-finite values or fewer than :data:`GCV_MIN_POINTS` particles.
    """
    X = _points(positions_um, "positions_um")
    Y = np.asarray(values, dtype=float)
    if Y.ndim == 1:
        Y = Y[:, None]
    if Y.ndim != 2 or Y.shape[0] != X.shape[0]:
        raise InputError(
            f"values must have shape (N,) or (N, C) with N = {X.shape[0]}, got {Y.shape}"
        )
    if not np.all(np.isfinite(Y)):
        raise InputError("values holds NaN or infinite values")
    n = X.shape[0]
    if n < GCV_MIN_POINTS:
        raise InputError(f"GCV needs at least {GCV_MIN_POINTS} particles, got {n}")
    scale = 1.0
    if n > max_points:
        keep = np.random.default_rng(seed).choice(n, size=int(max_points), replace=False)
        X, Y = X[keep], Y[keep]
        scale = n / float(max_points)
    basis = _ThinPlateBasis(X)
    return _gcv_choose(basis.gam, basis.to_modes(Y), np.linalg.norm(Y, axis=0)) * scale


#: A column whose non-affine part ``‖Bᵀ y‖`` is at most this fraction of ``‖y‖`` is exactly
#: affine (round-off): :func:`_gcv_choose` gives it the largest λ of the scan.
GCV_AFFINE_RTOL = 1e-11


def _gcv_choose(gam: np.ndarray, z: np.ndarray, y_norm: np.ndarray | None = None) -> np.ndarray:
    """GCV's λ for each column of ``z = Bᵀ y`` (shape (m − 4, C)), eigenvalues ``gam``;
    ``y_norm``: ``‖y‖`` of each column (exactly affine columns, see :func:`gcv_smoothing`)."""
    m = gam.size + 4
    z2 = z * z
    top = max(float(gam.max(initial=0.0)), np.finfo(float).tiny)
    lams = top * np.logspace(-12.0, 4.0, 161)
    f = lams[None, :] / (gam[:, None] + lams[None, :])  # (m - 4, L)
    rss = (f * f).T @ z2  # (L, C)
    tr = f.sum(axis=0)  # (L,)
    score = m * rss / (tr * tr)[:, None]
    best = np.argmin(score, axis=0)
    if y_norm is not None:
        affine = np.sqrt(z2.sum(axis=0)) <= GCV_AFFINE_RTOL * np.asarray(y_norm)
        best[affine] = lams.size - 1
    return lams[best]


class _ThinPlateBasis:
    """The eigen-basis of a thin-plate spline with a degree-1 polynomial on ``N`` centres.

    ``P = [1, X − X̄] = Q R`` (Householder QR, ``Q = H₀ H₁ H₂ H₃``, ``Q₁ R₁`` its thin part),
    ``Q₂`` the other ``N − 4`` columns of ``Q`` (an orthonormal basis of the null space of
    ``Pᵀ``), ``Q₂ᵀ K Q₂ = V diag(γ) Vᵀ`` and ``B = Q₂ V`` (N × (N − 4), orthonormal columns,
    orthogonal to ``Q₁``). Every smoothing parameter λ reuses it (:func:`gcv_smoothing`,
    :class:`_ThinPlateFit`).

    ``Qᵀ K Q`` is formed with the four reflectors (compact WY form ``Q = I − V T Vᵀ``: one
    rank-8 update, O(N²)) and ``B`` is applied through them (:meth:`to_modes`,
    :meth:`from_modes`) instead of as dense N × N products: the eigen-decomposition is then
    most of the cost.

    The eigen-decomposition is LAPACK's ``dsyevd`` (what :func:`numpy.linalg.eigh` calls)
    without its last step: ``Q₂ᵀ K Q₂ = Z T Zᵀ`` (``dsytrd``, ``T`` tridiagonal, ``Z`` kept as
    its Householder reflectors), ``T = S diag(γ) Sᵀ`` (``dstevd``, divide and conquer), and
    ``V = Z S`` is never formed: ``Z`` is applied to the few vectors that need it (``dormqr``,
    :meth:`_z`). The same γ and ``V`` as ``eigh`` without its N × N back-transformation
    (benchmarks/README.md, ``bench_fields.py``).
    """

    def __init__(self, X: np.ndarray) -> None:
        from scipy.linalg import qr
        from scipy.spatial.distance import cdist

        self.centre = X.mean(axis=0)
        self.Xc = X - self.centre
        m = X.shape[0]
        P = np.c_[np.ones(m), self.Xc]
        (h, tau), R = qr(P, mode="raw", check_finite=False)
        vs = np.zeros((4, m))
        for j in range(4):
            vs[j, j] = 1.0
            vs[j, j + 1 :] = h[j + 1 :, j]
        tau = np.asarray(tau, dtype=float)
        # Q = H₀ H₁ H₂ H₃ = I − V T Vᵀ (compact WY form, T upper triangular 4 × 4)
        V = np.ascontiguousarray(vs.T)
        T = np.zeros((4, 4))
        for j in range(4):
            T[j, j] = tau[j]
            T[:j, j] = -tau[j] * (T[:j, :j] @ (V[:, :j].T @ V[:, j]))
        self._V4, self._T4 = V, T
        self.R1 = np.triu(R[:4, :4])
        self.K = _tps_kernel_sq(cdist(self.Xc, self.Xc, "sqeuclidean"))
        # Qᵀ K Q = K − Z Vᵀ − V Zᵀ, Z = K V T − V Tᵀ (Vᵀ K V T) / 2: one rank-8 product, of
        # the rows and columns 4: only
        Y = (self.K @ V) @ T
        Z = Y - 0.5 * V @ (T.T @ (V.T @ Y))
        M2 = (
            self.K[4:, 4:]
            - np.concatenate([Z[4:], V[4:]], axis=1) @ np.concatenate([V[4:], Z[4:]], axis=1).T
        )
        e = np.zeros((m, 4))
        e[:4, :4] = np.eye(4)
        self.Q1 = self._apply_q(e)
        gam, self._S, self._zr, self._ztau = _eigh_reflected(0.5 * (M2 + M2.T))
        self.gam = np.maximum(gam, 0.0)

    def _z(self, Y: np.ndarray, transpose: bool = False) -> np.ndarray:
        """``Z Y`` (``Zᵀ Y`` with ``transpose``) for ``Y`` (N − 4, C): ``dsytrd``'s reflectors,
        as ``dormtr`` applies them (``dormqr`` on all rows but the first)."""
        Y = np.array(Y, dtype=float, order="F")
        if self._ztau.size == 0 or Y.shape[1] == 0:
            return Y
        from scipy.linalg import lapack

        # up to ~30 columns LAPACK's unblocked code (a workspace of one row) is the faster:
        # the blocked one builds a 64 × 64 triangular factor per block of reflectors
        k = Y.shape[1]
        lwork = k if k <= 32 else 64 * k + 65 * 64
        out, _, info = lapack.dormqr(
            "L", "T" if transpose else "N", self._zr, self._ztau, Y[1:], lwork, overwrite_c=1
        )
        if info != 0:
            raise np.linalg.LinAlgError(f"dormqr failed (info {info})")
        Y[1:] = out
        return Y

    @property
    def V(self) -> np.ndarray:
        """The eigenvectors ``V`` (N − 4, N − 4), formed (for tests and checks)."""
        return self._z(self._S)

    def _apply_q(self, Y: np.ndarray) -> np.ndarray:
        """``Q Y = Y − V (T (Vᵀ Y))`` (N, C) for ``Y`` (N, C)."""
        Y = np.asarray(Y, dtype=float)
        return Y - self._V4 @ (self._T4 @ (self._V4.T @ Y))

    def _apply_qt(self, Y: np.ndarray) -> np.ndarray:
        """``Qᵀ Y = Y − V (Tᵀ (Vᵀ Y))`` (N, C) for ``Y`` (N, C)."""
        Y = np.asarray(Y, dtype=float)
        return Y - self._V4 @ (self._T4.T @ (self._V4.T @ Y))

    def to_modes(self, Y: np.ndarray) -> np.ndarray:
        """``Bᵀ Y`` (N − 4, C) for ``Y`` (N, C)."""
        return self._S.T @ self._z(self._apply_qt(Y)[4:], transpose=True)

    def from_modes(self, Z: np.ndarray) -> np.ndarray:
        """``B Z`` (N, C) for ``Z`` (N − 4, C)."""
        W = np.zeros((Z.shape[0] + 4, Z.shape[1]))
        W[4:] = self._z(self._S @ Z)
        return self._apply_q(W)

    def columns(self, keep: np.ndarray) -> np.ndarray:
        """The columns ``B[:, keep]`` (N, r)."""
        W = np.zeros((self._S.shape[0] + 4, keep.size))
        W[4:] = self._z(self._S[:, keep])
        return self._apply_q(W)

    @property
    def B(self) -> np.ndarray:
        """``B`` (N, N − 4), formed (for tests and checks; the fits use :meth:`to_modes`)."""
        return self.columns(np.arange(self._S.shape[1]))


def _eigh_reflected(A: np.ndarray):
    """``A = Z S diag(γ) Sᵀ Zᵀ`` for a symmetric ``A`` (n, n): ``γ`` ascending (n,), ``S``
    (n, n) and ``dsytrd``'s reflectors of ``Z`` (``(n − 1, n − 1)`` and ``τ`` (n − 1,), empty
    for n < 2), see :class:`_ThinPlateBasis`. Raises :class:`numpy.linalg.LinAlgError`."""
    n = A.shape[0]
    if n < 2:
        gam, S = np.linalg.eigh(A)
        return gam, S, np.zeros((0, 0), order="F"), np.zeros(0)
    from scipy.linalg import lapack

    lwork, info = lapack.dsytrd_lwork(n, lower=1)
    c, d, e, tau, info = lapack.dsytrd(A, lower=1, lwork=int(lwork), overwrite_a=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"dsytrd failed (info {info})")
    gam, S, info = lapack.dstevd(d, e, compute_v=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"the eigenvalues did not converge (dstevd info {info})")
    return gam, S, np.asfortranarray(c[1:, :-1]), tau


__all__ = ["GCV_AFFINE_RTOL", "GCV_MIN_POINTS", "gcv_smoothing"]
