"""Evaluating a smoothing thin-plate spline fit: values, exact gradients and their standard
uncertainties at arbitrary points and on a grid (:class:`_ThinPlateFit`).

The fit is built from one :class:`track.thin_plate._ThinPlateBasis` and one λ per column
(:func:`track.thin_plate.gcv_smoothing`); :mod:`track.fields` wraps it in a
:class:`~track.fields.DisplacementInterpolant`.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from .errors import InputError
from .thin_plate import _ThinPlateBasis

if TYPE_CHECKING:
    from .grid import GridAxes

#: Modes of the spline whose filter factor γ/(γ + λ) is below this are left out of the
#: standard uncertainties at arbitrary points (their share of a node's variance is of the
#: order of its square times σ²): :meth:`DisplacementInterpolant.std`.
STD_MODE_CUTOFF = 1e-4
#: The same for the uncertainties of gridded fields (:func:`field_on_grid`), where the cost
#: matters (its accuracy: benchmarks/README.md, ``bench_fields.py``).
STD_GRID_MODE_CUTOFF = 3e-2
#: The gridded fields' uncertainties are computed on a sub-grid (every ``k``-th node along each
#: axis, and the last) whose spacing is at most this many median nearest-neighbour distances
#: of the particles, and interpolated (trilinear) in between: they vary over a particle
#: spacing, not a node spacing (its accuracy: benchmarks/README.md, ``bench_fields.py``).
#: 0: every node.
STD_GRID_SUB_SPACING = 1.0
#: Rows of query points evaluated at once (a block of ``rows × N`` kernel values).
_BLOCK_ROWS = 256
#: Smallest squared distance in the kernel (µm²): keeps ``log`` finite (in single precision)
#: at a centre.
_R2_FLOOR = 1e-30


class _ThinPlateFit:
    """Smoothing thin-plate splines (degree-1 polynomial) of the columns of ``Y``, each with
    its λ, from one :class:`_ThinPlateBasis`; values, analytic gradients and the standard
    uncertainties of both, with ``u(q) = k(q)ᵀ c + p(q)ᵀ d`` and ``p(q) = [1, q − X̄]``.

    For data ``y`` the fit is linear, ``u(q) = w(q)ᵀ y``, with
    ``w(q) = B diag(1/(γ + λ)) a(q) + Q₁ R₁⁻ᵀ p(q)`` and
    ``a(q) = Bᵀ k(q) − Bᵀ K Q₁ R₁⁻ᵀ p(q)``. ``[B, Q₁]`` is orthogonal, so with independent
    data errors of standard deviation ``σ_j``,
    ``var u(q) = Σ_j w_j(q)² σ_j² = fᵀ [B, Q₁]ᵀ diag(σ²) [B, Q₁] f`` with
    ``f = [a / (γ + λ), R₁⁻ᵀ p]``, and the same with ``∂/∂q`` for the gradient.
    """

    def __init__(
        self,
        basis: _ThinPlateBasis,
        Y: np.ndarray,
        lam: np.ndarray,
        sigma: np.ndarray | None = None,
    ) -> None:
        b = basis
        self.basis = b
        self.lam = np.asarray(lam, dtype=float)
        scale = max(float(b.gam.max(initial=0.0)), 1.0)
        den = b.gam[:, None] + self.lam[None, :]  # (N - 4, C)
        rdiag = np.abs(np.diag(b.R1))
        # four particles fix the affine part exactly: no spline mode (den is empty)
        if rdiag.min() <= 1e-10 * rdiag.max() or den.min(initial=np.inf) <= 1e-14 * scale:
            raise InputError(
                f"cannot fit a displacement field to {Y.shape[0]} particles: they are coplanar "
                "or repeated"
            )
        self.den = den
        self.z = b.to_modes(Y)  # (N - 4, C)
        C = b.from_modes(self.z / den)
        D = np.linalg.solve(b.R1, b.Q1.T @ (Y - b.K @ C - C * self.lam[None, :]))
        self.C, self.D = C, D
        nc = Y.shape[1]
        Xc = b.Xc
        # M @ [C, C_i X_j]: the gradient of Σ_k c_k φ(|q − x_k|) with φ'(r)/r = 2 log r + 1
        self._Cg = np.concatenate(
            [C] + [C[:, [i]] * Xc[:, [j]] for i in range(nc) for j in range(3)], axis=1
        )
        self._xsq = np.einsum("ij,ij->i", Xc, Xc)
        self._m2Xt = np.ascontiguousarray(-2.0 * Xc.T)
        # log r @ W gives values and gradients at once (:meth:`_value_gradient`)
        self._W = np.concatenate(
            [C, self._xsq[:, None] * C] + [Xc[:, [j]] * C for j in range(3)], axis=1
        )
        self._s0 = C.sum(axis=0)
        self._s1 = np.stack([(Xc[:, [j]] * C).sum(axis=0) for j in range(3)])  # (3, C)
        self._r2_scale = max(float(np.sum(np.ptp(Xc, axis=0) ** 2)), 1e-12)
        # r² / s = [q̃, 1, |q̃|²] @ _Xaug (one product, :meth:`_logs`)
        self._Xaug = np.vstack([self._m2Xt, self._xsq[None, :], np.ones((1, Xc.shape[0]))])
        self._Xaug /= self._r2_scale
        self._log_s = math.log(self._r2_scale)
        self._floor32 = np.float32(max(_R2_FLOOR / self._r2_scale, 1e-37))
        self._W_sum = self._W.sum(axis=0)
        self._W32 = self._W.astype(np.float32)  # the grid's product (:meth:`on_grid`)
        self.sigma = self._noise(sigma)

    # -- noise -------------------------------------------------------------------------------
    def _noise(self, sigma):
        """Per-datum, per-column σ (N, C): given, or ``RSS / tr((I − A)²)`` from the residuals
        (unbiased for noise on a field the spline reproduces; ``RSS / tr(I − A)`` would be
        biased low by up to 20 % for lightly smoothed fits, see the tests)."""
        n, nc = self.C.shape
        if sigma is not None:
            return np.broadcast_to(np.asarray(sigma, dtype=float), (n, nc))
        f = self.lam[None, :] / self.den  # (N - 4, C): filter of the residuals
        rss = np.sum((f * self.z) ** 2, axis=0)
        tr = np.sum(f * f, axis=0)
        with np.errstate(divide="ignore", invalid="ignore"):
            var = np.where(tr > 1e-9, rss / tr, np.nan)
        return np.broadcast_to(np.sqrt(var)[None, :], (n, nc))

    # -- evaluation --------------------------------------------------------------------------
    def _kernels(self, q: np.ndarray, single: bool = False, kernel: bool = True):
        """``q − X̄`` (P, 3), the kernel block ``r² log r`` (P, N; None unless ``kernel``) and
        ``log r`` (P, N).

        With ``single``, ``log`` is taken in single precision (a third of the time of
        double's; the rest stays double, and the log is of ``r²`` over the centres' squared
        extent, near 1): values and exact gradients then carry a relative error of about
        1e-7 of the field's magnitude (benchmarks/README.md), far below any noise, but too
        rough for finite
        differences with tiny steps, so only the gridded fields and the Eulerian composition
        (exact gradients) use it. ``r`` is clamped at ``sqrt(_R2_FLOOR)``: at a centre
        ``r² log r`` → 0 and its gradient term ``(q − x) φ'(r)/r`` → 0 with any finite log.
        """
        b = self.basis
        dq = q - b.centre
        r2 = dq @ self._m2Xt
        r2 += self._xsq[None, :]
        r2 += np.einsum("ij,ij->i", dq, dq)[:, None]
        np.maximum(r2, _R2_FLOOR, out=r2)
        if single:
            # log of r² over the centres' squared extent (near 1: smaller absolute error)
            l32 = np.empty(r2.shape, dtype=np.float32)
            np.multiply(r2, 1.0 / self._r2_scale, out=l32, casting="unsafe")
            np.log(l32, out=l32)
            logr = l32.astype(np.float64)
            logr += math.log(self._r2_scale)
        else:
            logr = np.log(r2)
        logr *= 0.5
        return dq, (np.multiply(r2, logr, out=r2) if kernel else None), logr

    def _logs(self, q: np.ndarray):
        """``q − X̄`` (P, 3) and ``log(r² / s)`` (P, N) in single precision, ``s`` the centres'
        squared extent (:meth:`_kernels`' ``single``; ``log r = (L + log s) / 2``): ``r²`` from
        one product in double precision, then scaled, floored and logged in float32."""
        dq = q - self.basis.centre
        A = np.empty((dq.shape[0], 5))
        A[:, :3] = dq
        A[:, 3] = 1.0
        A[:, 4] = np.einsum("ij,ij->i", dq, dq)
        L = np.empty((dq.shape[0], self._Xaug.shape[1]), dtype=np.float32)
        # floored in double and cast in one pass (the floor is a float32 value: the same L)
        np.maximum(A @ self._Xaug, float(self._floor32), out=L, casting="same_kind")
        np.log(L, out=L)
        return dq, L

    def _log_r_product(self, L: np.ndarray, W: np.ndarray, W_sum: np.ndarray) -> np.ndarray:
        """``log r @ W`` (P, K) from :meth:`_logs`' ``L`` and ``W_sum = W.sum(axis=0)`` (in
        double precision; the product in single precision when ``W`` is float32)."""
        M = np.asarray(L @ W, dtype=np.float64)
        M += self._log_s * W_sum
        M *= 0.5
        return M

    def _value_gradient(self, q: np.ndarray, logs=None):
        """Values (P, C) and ``∂u_i/∂x_j`` (P, C, 3) at ``q`` (P, 3) from one product
        ``log r @ W`` (single-precision log, :meth:`_logs`): with
        ``r² = |q̃|² + |x̃|² − 2 q̃·x̃`` (``~``: minus the centre),
        ``Σ c r² log r = |q̃|² (L c) + L (|x̃|² c) − 2 Σ_j q̃_j L (x̃_j c)`` and
        ``∂/∂q_j Σ c r² log r = q̃_j (2 L c + Σ c) − (2 L (x̃_j c) + Σ x̃_j c)``."""
        dq, L = self._logs(q) if logs is None else logs
        return self._from_products(dq, self._log_r_product(L, self._W, self._W_sum))

    def _from_products(self, dq: np.ndarray, M: np.ndarray):
        """:meth:`_value_gradient` from ``q̃`` (P, 3) and the products ``M = log r @ W``
        (P, 5 C)."""
        nc = self.C.shape[1]
        M0, M1 = M[:, :nc], M[:, nc : 2 * nc]
        Mx = M[:, 2 * nc :].reshape(-1, 3, nc)  # (P, j, c)
        u = np.einsum("ij,ij->i", dq, dq)[:, None] * M0 + M1
        u -= 2.0 * np.einsum("pj,pjc->pc", dq, Mx)
        u += self.D[0] + dq @ self.D[1:]
        G = dq[:, None, :] * (2.0 * M0 + self._s0)[:, :, None]  # (P, c, j)
        G -= np.swapaxes(2.0 * Mx + self._s1[None], 1, 2)
        G += self.D[1:].T[None, :, :]
        return u, G

    def evaluate(self, q: np.ndarray, gradient: bool = False, single: bool = False):
        """Values (P, C) and, with ``gradient``, ``∂u_i/∂x_j`` (P, C, 3) at ``q`` (P, 3);
        ``single``: see :meth:`_kernels`."""
        q = np.asarray(q, dtype=float).reshape(-1, 3)
        nc = self.C.shape[1]
        u = np.empty((q.shape[0], nc))
        G = np.empty((q.shape[0], nc, 3)) if gradient else None
        for s in range(0, q.shape[0], _BLOCK_ROWS):
            if gradient and single:
                u[s : s + _BLOCK_ROWS], G[s : s + _BLOCK_ROWS] = self._value_gradient(
                    q[s : s + _BLOCK_ROWS]
                )
                continue
            dq, Kq, logr = self._kernels(q[s : s + _BLOCK_ROWS], single)
            u[s : s + _BLOCK_ROWS] = Kq @ self.C + self.D[0] + dq @ self.D[1:]
            if gradient:
                logr *= 2.0
                logr += 1.0  # φ'(r)/r
                MC = logr @ self._Cg
                g = dq[:, None, :] * MC[:, :nc, None] - MC[:, nc:].reshape(-1, nc, 3)
                G[s : s + _BLOCK_ROWS] = g + self.D[1:].T[None, :, :]
        return u, G

    def _modes(self, cutoff: float = 0.0) -> np.ndarray:
        """Indices of the modes whose filter factor γ/(γ + λ) reaches ``cutoff`` for the
        least smoothed column."""
        lam = float(self.lam.min())
        g = self.basis.gam
        return np.flatnonzero(g >= cutoff * (g + lam))

    def _std_setup(self, cutoff: float):
        """Mode indices, ``Bₖ``, ``H``, ``R₁⁻¹`` and the quadratic form of each column."""
        b = self.basis
        keep = self._modes(cutoff)
        Bk = b.columns(keep)
        R1inv = np.linalg.inv(b.R1)  # (4, 4)
        H = (Bk.T @ (b.K @ b.Q1)) @ R1inv.T  # (r, 4): a(q) = Bₖᵀ k(q) − H p(q)
        Ob = None  # [Bₖ, Q₁] (N, r + 4), orthonormal columns (formed when needed)
        quads = []  # None: one σ for the column ([B, Q₁] orthogonal: fᵀ Obᵀ σ² Ob f = σ² |f|²)
        for c in range(self.C.shape[1]):
            sc = self.sigma[:, c]
            if np.all(sc == sc[0]):
                quads.append(None)
            else:
                if Ob is None:
                    Ob = np.concatenate([Bk, b.Q1], axis=1)
                S = Ob.T @ (Ob * (sc**2)[:, None])
                quads.append(lambda f, S=S: np.einsum("ij,ij->i", f @ S, f))
        return keep, Bk, H, R1inv, quads

    def _var(self, a, pt, keep, quads) -> np.ndarray:
        """``var`` (P, C) of ``w = [B, Q₁] [a / (γ + λ_c), pt]`` for features ``a`` (P, r) and
        ``pt`` (P, 4)."""
        nc = self.C.shape[1]
        out = np.empty((a.shape[0], nc))
        den = self.den[keep]  # (r, C)
        homo = [c for c in range(nc) if quads[c] is None]
        if homo:
            s2 = self.sigma[0, homo] ** 2
            out[:, homo] = (
                (a * a) @ (den[:, homo] ** -2.0) + np.sum(pt * pt, axis=1)[:, None]
            ) * s2
        for c in range(nc):
            if quads[c] is not None:
                out[:, c] = quads[c](np.concatenate([a / den[:, c], pt], axis=1))
        return out

    def std(
        self,
        q: np.ndarray,
        gradient: bool = False,
        cutoff: float = STD_MODE_CUTOFF,
        single: bool = False,
    ):
        """Standard uncertainties of :meth:`evaluate`: (P, C) and (P, C, 3) or None, from the
        modes above ``cutoff`` (:meth:`_modes`); ``single``: see :meth:`_kernels`."""
        q = np.asarray(q, dtype=float).reshape(-1, 3)
        nc = self.C.shape[1]
        setup = self._std_features(cutoff) if single else self._std_setup(cutoff)
        u_sd = np.empty((q.shape[0], nc))
        G_sd = np.empty((q.shape[0], nc, 3)) if gradient else None
        for s in range(0, q.shape[0], _BLOCK_ROWS):
            blk = slice(s, s + _BLOCK_ROWS)
            if single:
                u_sd[blk], g = self._std_from_logs(self._logs(q[blk]), setup, gradient)
            else:
                u_sd[blk], g = self._std_block(q[blk], setup, gradient)
            if gradient:
                G_sd[blk] = g
        return u_sd, G_sd

    def _std_features(self, cutoff: float):
        """:meth:`_std_setup` and the weights of ``log r`` giving ``a`` and ``∂a/∂q`` at once
        (:meth:`_std_from_logs`): ``[Bₖ, |x̃|² Bₖ, x̃_x Bₖ, x̃_y Bₖ, x̃_z Bₖ]`` (N, 5 r)."""
        keep, Bk, H, R1inv, quads = self._std_setup(cutoff)
        Xc = self.basis.Xc
        r = keep.size
        # float32 weights: the product is the largest of the grid (P × N × 5 r) and variances
        # need no more (benchmarks/README.md, bench_fields.py); each block computed in double
        # and rounded once
        scales = np.vstack([np.ones(Xc.shape[0]), self._xsq, Xc.T])  # (5, N)
        Wb = np.empty((Xc.shape[0], 5 * r), dtype=np.float32)
        Wb[:, :r] = Bk
        for s in range(1, 5):
            np.multiply(scales[s][:, None], Bk, out=Wb[:, s * r : (s + 1) * r], casting="same_kind")
        return keep, Bk, H, R1inv, quads, Wb, (scales @ Bk).ravel()

    def _std_block(self, q, setup, gradient):
        """:meth:`std` in double precision for one block of points."""
        keep, Bk, H, R1inv, quad = setup[:5]
        Xc = self.basis.Xc
        r = keep.size
        dq, Kq, logr = self._kernels(q)
        p = np.c_[np.ones(dq.shape[0]), dq]
        a = Kq @ Bk - p @ H.T  # (P, r)
        pt = p @ R1inv  # R₁⁻ᵀ p, as rows
        u_sd = np.sqrt(self._var(a, pt, keep, quad))
        if not gradient:
            return u_sd, None
        G_sd = np.empty((q.shape[0], self.C.shape[1], 3))
        logr *= 2.0
        logr += 1.0
        cols = np.concatenate([Bk] + [Xc[:, [j]] * Bk for j in range(3)], axis=1)
        MB = logr @ cols  # (P, 4r)
        for j in range(3):
            da = dq[:, [j]] * MB[:, :r] - MB[:, (j + 1) * r : (j + 2) * r] - H[:, 1 + j]
            dpt = np.broadcast_to(R1inv[1 + j], (dq.shape[0], 4))
            G_sd[:, :, j] = np.sqrt(self._var(da, dpt, keep, quad))
        return u_sd, G_sd

    def _std_from_logs(self, logs, setup, gradient: bool = True):
        """:meth:`std` at the points of :meth:`_logs`' ``(q̃, L)``, from one product
        ``log r @ [Bₖ, |x̃|² Bₖ, x̃_j Bₖ]`` (``setup``: :meth:`_std_features`): with
        ``M_b = log r @ Bₖ``, ``M_s = log r @ (|x̃|² Bₖ)``, ``M_j = log r @ (x̃_j Bₖ)``,
        ``Bₖᵀ k(q) = |q̃|² M_b + M_s − 2 Σ_j q̃_j M_j`` and, with ``φ'(r)/r = 2 log r + 1``,
        ``∂(Bₖᵀ k)/∂q_j = q̃_j (2 M_b + Σ Bₖ) − (2 M_j + Σ x̃_j Bₖ)``."""
        keep, _, H, R1inv, quad, Wb, Wb_sum = setup
        dq, L = logs
        n, r = dq.shape[0], keep.size
        M = self._log_r_product(L, Wb, Wb_sum).reshape(n, 5, r)  # M_b, M_s, M_x, M_y, M_z
        p = np.c_[np.ones(n), dq]
        # features of u and of its three derivatives, stacked: one variance product for all
        a = np.empty((4 if gradient else 1, n, r))
        pt = np.empty((a.shape[0], n, 4))
        coef = np.empty((n, 5))  # a = Σ_t coef_t M_t − p Hᵀ
        coef[:, 0] = np.einsum("ij,ij->i", dq, dq)
        coef[:, 1] = 1.0
        np.multiply(dq, -2.0, out=coef[:, 2:])
        np.einsum("pt,ptk->pk", coef, M, out=a[0])
        a[0] -= p @ H.T
        pt[0] = p @ R1inv
        if gradient:
            phi_b = 2.0 * M[:, 0]
            phi_b += Wb_sum[:r]
            for j in range(3):
                np.multiply(dq[:, [j]], phi_b, out=a[1 + j])
                a[1 + j] -= 2.0 * M[:, 2 + j]
                a[1 + j] -= Wb_sum[(2 + j) * r : (3 + j) * r] + H[:, 1 + j]
                pt[1 + j] = R1inv[1 + j]
        m = a.shape[0] * n
        sd = np.sqrt(self._var(a.reshape(m, r), pt.reshape(m, 4), keep, quad))
        sd = sd.reshape(a.shape[0], n, sd.shape[1])
        if not gradient:
            return sd[0], None
        return sd[0], np.moveaxis(sd[1:], 0, -1)

    def on_grid(self, axes: GridAxes, with_std: bool, stride: int | None = None):
        """Values, exact gradients and (``with_std``) standard uncertainties on a grid.

        One single-precision ``log r`` block per chunk of nodes (:meth:`_logs`) gives values
        and gradients, its product with the weights ``W`` in single precision too (the
        values and gradients within about 1e-5 of the field's magnitude of the
        double-precision product: benchmarks/README.md, ``bench_fields.py``), and, on the
        nodes of the sub-grid, the uncertainties: they keep the modes
        above :data:`STD_GRID_MODE_CUTOFF`, are computed on every ``stride``-th node along each
        axis (the last node always; default :meth:`_std_stride`) and interpolated (trilinear)
        at the other nodes.

        Returns
        -------
        u : (nz, ny, nx, C), G : (nz, ny, nx, C, 3), u_std, G_std : the same or None
        """
        pts = axes.points()
        shape = axes.shape
        nc = self.C.shape[1]
        M = np.empty((pts.shape[0], self._W.shape[1]))  # log r @ W of every node
        rest = np.arange(pts.shape[0])
        if with_std:  # the sub-grid's nodes first: their log r blocks serve both
            if stride is None:
                stride = self._std_stride(axes)
            sub = [_sub_indices(n, max(1, int(stride))) for n in shape]
            on_sub = np.zeros(shape, dtype=bool)
            on_sub[np.ix_(*sub)] = True
            first, rest = np.flatnonzero(on_sub), np.flatnonzero(~on_sub)
            setup = self._std_features(STD_GRID_MODE_CUTOFF)
            u_sd, G_sd = np.empty((first.size, nc)), np.empty((first.size, nc, 3))
            for s in range(0, first.size, _BLOCK_ROWS):
                idx = first[s : s + _BLOCK_ROWS]
                logs = self._logs(pts[idx])
                M[idx] = self._log_r_product(logs[1], self._W32, self._W_sum)
                u_sd[s : s + _BLOCK_ROWS], G_sd[s : s + _BLOCK_ROWS] = self._std_from_logs(
                    logs, setup
                )
        for s in range(0, rest.size, _BLOCK_ROWS):
            idx = rest[s : s + _BLOCK_ROWS] if with_std else slice(s, s + _BLOCK_ROWS)
            M[idx] = self._log_r_product(self._logs(pts[idx])[1], self._W32, self._W_sum)
        # values and gradients of all nodes at once (:meth:`_value_gradient`)
        u, G = self._from_products(pts - self.basis.centre, M)
        u, G = u.reshape(*shape, nc), G.reshape(*shape, nc, 3)
        if not with_std:
            return u, G, None, None
        sub_shape = tuple(ix.size for ix in sub)
        u_sd = _upsample(u_sd.reshape(*sub_shape, nc), sub, shape)
        G_sd = _upsample(G_sd.reshape(*sub_shape, nc, 3), sub, shape)
        return u, G, u_sd, G_sd

    def _std_stride(self, axes: GridAxes) -> int:
        """Node stride of the uncertainties' sub-grid: its spacing at most about (+20 %)
        :data:`STD_GRID_SUB_SPACING` median nearest-neighbour distances of the centres."""
        from scipy.spatial import cKDTree

        Xc = self.basis.Xc
        if STD_GRID_SUB_SPACING <= 0 or Xc.shape[0] < 2:
            return 1
        d, _ = cKDTree(Xc).query(Xc, k=2)
        h = max(axes.spacing_xyz_um)
        # 20 % leeway: an increment's matched particles are spaced a little unlike frame 0's,
        # whose spacing set the grid (nodes_per_spacing = 2 must give 2, not 1)
        return max(1, int(STD_GRID_SUB_SPACING * float(np.median(d[:, 1])) / h + 0.2))


def _sub_indices(n: int, stride: int) -> np.ndarray:
    """Every ``stride``-th index of ``range(n)`` and the last."""
    ix = np.arange(0, n, stride)
    return ix if ix[-1] == n - 1 else np.r_[ix, n - 1]


def _upsample(a: np.ndarray, sub: list, shape: tuple) -> np.ndarray:
    """Linear interpolation along the first three axes of ``a`` (values at the indices
    ``sub[k]`` of axis ``k``) onto ``shape``; ``sub[k]`` increasing, from 0 to ``shape[k] − 1``."""
    for ax, (ix, n) in enumerate(zip(sub, shape, strict=True)):
        if ix.size == n:
            continue
        k = np.clip(np.searchsorted(ix, np.arange(n), side="right") - 1, 0, ix.size - 2)
        w = (np.arange(n) - ix[k]) / (ix[k + 1] - ix[k])
        w = w.reshape((-1,) + (1,) * (a.ndim - ax - 1))
        lo, hi = np.take(a, k, axis=ax), np.take(a, k + 1, axis=ax)
        a = lo + w * (hi - lo)
    return a
