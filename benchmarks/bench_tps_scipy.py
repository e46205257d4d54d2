"""The fields' thin-plate spline against scipy's (run by hand, not in CI).

Does :class:`scipy.interpolate.RBFInterpolator` (``kernel="thin_plate_spline"``, ``degree=1``,
``smoothing`` = the λ that GCV chose for each displacement component) give the same gridded
fields as :func:`track.fields.gridded_field`'s own solver, and at what cost?

A pair from :func:`track.synthetic.make_pair` (``--field``, default ``stiff_inclusion``; about
``--n`` particles, localisation noise 0.25 µm laterally and 2.5 µm axially) is gridded on the
default grid (``GridSettings()``, 50 000 nodes) and on the particle-density grid
(``nodes_per_spacing=2``). For each grid it prints

* ``du_max``: the largest difference of the displacement at the nodes (µm), against ours as
  gridded (single-precision ``log r``) and as evaluated point by point in double precision
  (``du_max_double``);
* ``dE_max (grad)``: the largest difference of the Green–Lagrange strain between scipy's field
  differentiated on the grid (:func:`numpy.gradient`, the only gradient scipy's interpolant
  has) and ours with the same differences (the solvers compared alone), and ``dE_max (exact)``
  against ours with its exact gradients (what ``track`` writes);
* ``E_rmse``: the strain error against the known field over the supported nodes, for ours
  (exact gradients) and for scipy's (grid differences);
* CPU seconds: ours (fit with GCV, values and exact gradients on the grid; with and without
  the standard uncertainties) and scipy's (the same λ from :func:`track.fields.gcv_smoothing`,
  then the fit, the values on the grid and :func:`numpy.gradient`).

Usage (from the repository root)::

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=. python benchmarks/bench_tps_scipy.py [--n 550]
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

#: The six independent components of a symmetric 3 × 3 tensor.
_UPPER = np.triu_indices(3)


def _cpu(fn):
    c0 = time.process_time()
    out = fn()
    return out, time.process_time() - c0


def _scipy_field(X, U, lam, axes):
    """scipy's smoothing thin-plate spline with ``lam`` per component on ``axes``: ``u`` (grid,
    3) and the strains by :func:`track.fields.strain_from_displacement`."""
    from scipy.interpolate import RBFInterpolator

    from track.fields import strain_from_displacement

    pts = axes.points()
    u = np.empty((pts.shape[0], 3))
    for c in range(3):
        f = RBFInterpolator(X, U[:, c], kernel="thin_plate_spline", degree=1, smoothing=lam[c])
        u[:, c] = f(pts)
    u = u.reshape(*axes.shape, 3)
    F, E, _ = strain_from_displacement(axes, u)
    return u, F, E


def _truth_E(field, axes):
    from track.strain import green_lagrange

    G = field.gradient(axes.points())
    return green_lagrange(np.eye(3) + G).reshape(*axes.shape, 3, 3)


def main() -> None:
    from track.fields import (
        GridSettings,
        fit_displacement,
        gcv_smoothing,
        grid_axes,
        grid_spacing_um,
        gridded_field,
        strain_from_displacement,
    )
    from track.synthetic import make_pair

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=550, help="particles seeded in the box")
    ap.add_argument("--field", default="stiff_inclusion")
    ap.add_argument("--amplitude", type=float, default=0.5, help="largest step (spacings)")
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args()
    pair = make_pair(a.field, a.n, a.amplitude, seed=a.seed)
    m = pair.true_matches()
    X = pair.ref_xyz_um[m[:, 0]]
    U = pair.def_xyz_um[m[:, 1]] - X
    print(f"{a.field}: {X.shape[0]} matched particles")
    rows = []
    for name, settings in (
        ("default", GridSettings()),
        ("particles", GridSettings(nodes_per_spacing=2.0)),
    ):
        axes = grid_axes(X, grid_spacing_um(X, settings), target_nodes=settings.target_nodes)
        ours, t_ours = _cpu(lambda s=settings, ax=axes: gridded_field(X, U, s, axes=ax))
        nostd = dataclasses.replace(settings, uncertainty=False)
        _, t_nostd = _cpu(lambda s=nostd, ax=axes: gridded_field(X, U, s, axes=ax))
        interp = fit_displacement(X, U, settings)
        lam = np.asarray(interp.smoothing)
        u_double = interp(axes.points()).reshape(*axes.shape, 3)  # double-precision log

        def scipy_run(lam=lam, ax=axes, k=settings.gcv_max_points):
            gcv_smoothing(X, U, max_points=k)  # the λ scipy lacks
            return _scipy_field(X, U, lam, ax)

        (u_s, _, E_s), t_scipy = _cpu(scipy_run)
        _, E_fd, _ = strain_from_displacement(axes, ours.u)
        truth = _truth_E(pair.field, axes)
        mask = ours.mask

        def rmse(E, truth=truth, mask=mask, iu=_UPPER):
            d = (E - truth)[mask][:, iu[0], iu[1]]
            return float(np.sqrt(np.mean(d**2)))

        rows.append(
            (
                name,
                "×".join(map(str, axes.shape)),
                float(np.max(np.abs(u_s - ours.u))),
                float(np.max(np.abs(u_s - u_double))),
                float(np.max(np.abs(E_s - E_fd))),
                float(np.max(np.abs(E_s - ours.E))),
                rmse(ours.E),
                rmse(E_s),
                t_ours,
                t_nostd,
                t_scipy,
            )
        )
    head = (
        "grid       nodes     du_max_um  du_max_double  dE_max(grad)  dE_max(exact)  "
        "E_rmse_ours  E_rmse_scipy  cpu_ours_s  cpu_ours_nostd_s  cpu_scipy_s"
    )
    print(head)
    for r in rows:
        print(
            f"{r[0]:<10} {r[1]:<9} {r[2]:<10.2e} {r[3]:<14.2e} {r[4]:<13.2e} {r[5]:<14.2e} "
            f"{r[6]:<12.3e} {r[7]:<13.3e} {r[8]:<11.2f} {r[9]:<17.2f} {r[10]:.2f}"
        )


if __name__ == "__main__":
    main()
