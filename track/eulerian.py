"""Eulerian cumulation of incremental displacement fields on the fixed reference grid.

Eulerian cumulation (the MATLAB reference composes in reverse order and symmetrises the
increment, which loses rotation; here the composition is exact):

Let ``X`` be a node of the fixed reference grid (frame 0 configuration), ``u_prev(X)`` and
``F_prev(X)`` the totals up to frame ``i−1``, and ``u_inc``, ``F_inc = I + ∂u_inc/∂x`` the
increment ``i−1 → i``, a field over the frame ``i−1`` configuration ``x``. The material
point ``X`` sits at ``x(X) = X + u_prev(X)`` in frame ``i−1``, so

    u_total(X) = u_prev(X) + u_inc(x(X))
    F_total(X) = F_inc(x(X)) · F_prev(X)

``u_inc`` and ``F_inc`` are evaluated **at the displaced positions** ``x(X)`` from the
increment's continuous interpolant (:func:`track.fields.fit_displacement`); ``∂u_inc/∂x``
exactly for the global thin-plate spline (one kernel evaluation gives values and gradients),
otherwise by central differences with the grid spacing as step (the same stencil
:func:`numpy.gradient` uses on the grid). By the chain rule ``F_total = I + ∂u_total/∂X``,
and the node is supported (:attr:`GridField.mask`) only while every increment was supported
at ``x(X)``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .fields import DisplacementInterpolant, strain_std
from .grid import GridAxes, GridField
from .strain import green_lagrange, infinitesimal


def compose_step(
    reference_um: np.ndarray,
    u_prev_um: np.ndarray,
    F_prev: np.ndarray,
    increment: DisplacementInterpolant,
    step_um: float | tuple,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One Eulerian cumulation step at reference points ``X``.

    Parameters
    ----------
    reference_um : ndarray, shape (P, 3)
        Reference positions ``X`` (µm).
    u_prev_um : ndarray, shape (P, 3)
        Total displacement up to the previous frame at ``X``.
    F_prev : ndarray, shape (P, 3, 3)
        Total deformation gradient up to the previous frame at ``X``.
    increment : DisplacementInterpolant
        Increment field over the previous frame's configuration.
    step_um : float or (hx, hy, hz)
        Central-difference step for ``∂u_inc/∂x`` where the interpolant has no exact
        gradient (:meth:`~track.fields.DisplacementInterpolant.value_and_gradient`).

    Returns
    -------
    u_total : ndarray, shape (P, 3)
        ``u_prev(X) + u_inc(X + u_prev(X))``.
    F_total : ndarray, shape (P, 3, 3)
        ``F_inc(X + u_prev(X)) · F_prev(X)``.
    supported : ndarray of bool, shape (P,)
        Whether the increment is supported by data at ``X + u_prev(X)``.
    """
    x = np.asarray(reference_um, float) + np.asarray(u_prev_um, float)
    u_inc, G_inc = increment.value_and_gradient(x, step_um)
    F_inc = np.eye(3) + G_inc
    F_total = np.einsum("pij,pjk->pik", F_inc, np.asarray(F_prev, float))
    return np.asarray(u_prev_um, float) + u_inc, F_total, increment.supported(x)


class EulerianCumulation:
    """Total fields on the reference grid, one increment at a time (module docstring).

    Parameters
    ----------
    axes : GridAxes
        Reference grid (frame 0 configuration).
    """

    def __init__(self, axes: GridAxes) -> None:
        self.axes = axes
        self._X = axes.points()
        self._u = np.zeros_like(self._X)
        self._F = np.broadcast_to(np.eye(3), (self._X.shape[0], 3, 3)).copy()
        self._mask = np.ones(self._X.shape[0], dtype=bool)
        self._var = None  # accumulated variances of u and ∂u/∂X
        self._with_std = True

    def add(
        self, increment: DisplacementInterpolant, increment_field: GridField | None = None
    ) -> GridField:
        """Compose the next increment (a field over the previous frame's configuration);
        the total field from frame 0 to the increment's deformed frame.

        Standard uncertainties (when the increments have them): the variances of the
        increments at the displaced positions add up, as for independent increments
        (``u_std² = Σ_k u_std,k²``, the same for ``F_std``; the first-order product rule is
        left out). Consecutive increments share a frame's localisation noise, with opposite
        signs, but drop-outs and each increment's own smoothing keep most of it from
        cancelling (coverage of this σ: docs/validation_notes.md, "Gridded fields").

        ``increment_field``, the increment gridded on the same grid (:func:`field_on_grid`),
        lends its values, gradients and uncertainties at the displaced positions
        (:func:`_grid_lookup`: trilinear gradients and σ, Taylor-corrected values), instead
        of evaluating the spline there: exact for the first increment and for affine fields,
        second order in the node spacing elsewhere (docs/validation_notes.md). Without it
        the spline is evaluated (:meth:`DisplacementInterpolant.value_and_gradient`,
        :meth:`~DisplacementInterpolant.std`).
        """
        x = self._X + self._u
        self._with_std &= increment.has_uncertainty
        on_grid = increment_field is not None and increment_field.shape == self.axes.shape
        u_sd = G_sd = None
        if on_grid:
            std = self._with_std and increment_field.u_std is not None
            got = _grid_lookup(increment_field, x, values=True, std=std)
            u_inc, G_inc = got[:2]
            if std:
                u_sd, G_sd = got[2:]
        else:
            u_inc, G_inc = increment.value_and_gradient(x, self.axes.spacing_xyz_um)
        self._F = np.matmul(np.eye(3) + G_inc, self._F)  # (compose_step)
        self._u = self._u + u_inc
        keep = np.flatnonzero(self._mask)  # a node once unsupported stays so
        # a new array: the fields returned before keep theirs (their files may still be
        # being written, by the writer threads of track.pipeline, while this one is made)
        mask = self._mask.copy()
        mask[keep] = increment.supported(x[keep])
        self._mask = mask
        shape = self.axes.shape
        Fg = self._F.reshape(*shape, 3, 3)
        stds = {}
        if self._with_std:
            if u_sd is None:
                u_sd, G_sd = increment.std(x)
            var = (u_sd**2, G_sd**2)
            if self._var is not None:
                var = (self._var[0] + var[0], self._var[1] + var[1])
            self._var = var
            G_sd = np.sqrt(var[1]).reshape(*shape, 3, 3)
            stds = {
                "u_std": np.sqrt(var[0]).reshape(*shape, 3),
                "F_std": G_sd,
                "e_std": strain_std(G_sd),
            }
        return GridField(
            self.axes.x_um,
            self.axes.y_um,
            self.axes.z_um,
            self._u.reshape(*shape, 3),
            Fg,
            green_lagrange(Fg),
            infinitesimal(Fg),
            self._mask.reshape(shape),
            **stds,
        )


def _trilinear(fld: GridField, values: np.ndarray, xyz_um: np.ndarray) -> np.ndarray:
    """Trilinear interpolation of nodal ``values`` (nodes, C) of ``fld``'s grid at ``xyz_um``
    (P, 3); outside the grid, the nearest border cell's weights (clamped). Returns (P, C)."""
    from scipy.sparse import csr_matrix

    shape = np.asarray(fld.shape)
    h = np.asarray(fld.spacing_xyz_um)[::-1]
    t = (np.asarray(xyz_um, float)[:, ::-1] - np.asarray(fld.origin_xyz_um)[::-1]) / h  # z,y,x
    t = np.clip(t, 0.0, shape - 1.0)
    i0 = np.minimum(np.floor(t).astype(np.int64), shape - 2)
    w = t - i0
    strides = np.array([shape[1] * shape[2], shape[2], 1])
    base = i0 @ strides
    ws = (1.0 - w, w)
    n = t.shape[0]
    # the eight corners' weights as a sparse (P, nodes) matrix: one product for all columns
    # (the same sums, in the same order, as adding the corners one by one; 5x faster)
    wt, idx = np.empty((n, 8)), np.empty((n, 8), dtype=np.int64)
    for corner in range(8):
        d = ((corner >> 2) & 1, (corner >> 1) & 1, corner & 1)
        wt[:, corner] = ws[d[0]][:, 0] * ws[d[1]][:, 1] * ws[d[2]][:, 2]
        idx[:, corner] = base + int(np.dot(d, strides))
    A = csr_matrix((wt.ravel(), idx.ravel(), np.arange(0, 8 * n + 1, 8)), (n, values.shape[0]))
    return np.asarray(A @ values)


def _grid_lookup(fld: GridField, xyz_um: np.ndarray, *, values: bool = False, std: bool = True):
    """A gridded field at ``xyz_um`` (P, 3), from its nodes only.

    Returns ``(u, G)`` when ``values`` — the displacement (P, 3) and ``∂u_i/∂x_j`` (P, 3, 3):
    the gradient trilinear in the nodes' exact gradients (second order in the node spacing),
    the displacement the same weighting of each corner's first-order Taylor value
    ``u(c) + G(c) (x − c)``, exact at the nodes and on affine fields (linear extrapolation
    from the border cells outside the grid) — followed, when ``std``, by ``u_std`` (P, 3) and
    ``F_std`` (P, 3, 3), trilinear.
    """
    n = np.shape(xyz_um)[0]
    cols = []
    if values:
        G = (fld.F - np.eye(3)).reshape(-1, 3, 3)
        nodes = fld.axes.points()
        # Σ_c w_c (u_c + G_c (x − c)) = Σ_c w_c (u_c − G_c c) + (Σ_c w_c G_c) x
        cols += [fld.u.reshape(-1, 3) - np.einsum("nij,nj->ni", G, nodes), G.reshape(-1, 9)]
    if std:
        cols += [fld.u_std.reshape(-1, 3), fld.F_std.reshape(-1, 9)]
    out = _trilinear(fld, np.concatenate(cols, axis=1), xyz_um)
    got = []
    if values:
        G = out[:, 3:12].reshape(n, 3, 3)
        got += [out[:, :3] + np.einsum("pij,pj->pi", G, np.asarray(xyz_um, float)), G]
        out = out[:, 12:]
    if std:
        got += [out[:, :3], out[:, 3:].reshape(n, 3, 3)]
    return tuple(got)


def cumulate_eulerian(
    axes: GridAxes, increments: Sequence[DisplacementInterpolant]
) -> list[GridField]:
    """Total fields on the reference grid from a sequence of increment fields.

    Parameters
    ----------
    axes : GridAxes
        Reference grid (frame 0 configuration).
    increments : sequence of DisplacementInterpolant
        Increment ``k`` (frame ``k → k+1``) is a field over the frame ``k`` configuration.

    Returns
    -------
    list of GridField
        Entry ``k``: total displacement and ``F = F_inc,k · … · F_inc,0`` from frame 0 to
        frame ``k + 1`` (module docstring), with ``E`` and ``e`` of that ``F``.
    """
    cumulation = EulerianCumulation(axes)
    return [cumulation.add(inc) for inc in increments]


__all__ = ["EulerianCumulation", "compose_step", "cumulate_eulerian"]
