"""Scores of a linker on synthetic clouds against their known truth: :func:`score_link` for a
:class:`track.synthetic.SyntheticPair`, :func:`score_motion` for clouds moved by a known
motion."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import cKDTree

if TYPE_CHECKING:
    from .synthetic import SyntheticPair


@dataclass(frozen=True)
class LinkScore:
    """How a linker did on a :class:`SyntheticPair`.

    Attributes
    ----------
    tracking_ratio : float
        Correct links / particles present in both frames.
    face_tracking_ratio : float
        The same among particles within one mean spacing of a face of the box.
    wrong_fraction : float
        Wrong links / links.
    n_common, n_links, n_wrong, n_face : int
        Particles in both frames, links, wrong links, common particles near a face.
    excess_rmse_spacings : float
        Displacement RMSE of the links above the localisation-noise floor, in mean spacings:
        ``sqrt(Σ_axes max(mean(e_a²) − mean(f_a²), 0))`` with ``e`` the error of each linked
        displacement against the true one and ``f`` the noise it should carry (the realised
        ``noise_def − noise_ref`` of a correct link, ``2 σ_a²`` in mean for a wrong one).
        Zero when every link is right.
    raw_rmse_xyz_spacings : tuple of float
        Per-axis RMSE of the linked displacements against the truth (mean spacings): noise
        included.
    field_rmse_xyz_spacings : tuple of float
        Per-axis RMSE of the linker's regularised field at the true positions of the linked
        particles (mean spacings); nan when the result has no field.
    """

    tracking_ratio: float
    face_tracking_ratio: float
    wrong_fraction: float
    n_common: int
    n_links: int
    n_wrong: int
    n_face: int
    excess_rmse_spacings: float
    raw_rmse_xyz_spacings: tuple[float, float, float]
    field_rmse_xyz_spacings: tuple[float, float, float]


def score_motion(result, x_um, motion, ids_ref, ids_def) -> tuple[float, int, float, float]:
    """Score a :class:`track.matching.LinkResult` of clouds made from ``x_um`` by ``motion``.

    Parameters
    ----------
    result : LinkResult
    x_um : ndarray, shape (N, 3)
        The particles before the motion (µm).
    motion : callable
        ``motion(points (P, 3)) -> moved points (P, 3)``.
    ids_ref, ids_def : ndarray of int
        Row ``i`` of the reference (deformed) cloud is particle ``ids_ref[i]`` (``ids_def[i]``).

    Returns
    -------
    tracking_ratio : float
        Right matches over the particles present in both clouds.
    wrong : int
        Wrong matches.
    rmse_matches, rmse_field : float
        RMS error of the matched displacements and of the fitted field at the matched
        particles, in mean spacings.
    """
    d, _ = cKDTree(x_um).query(x_um, 2)
    s = float(d[:, 1].mean())
    m = result.matches
    good = ids_ref[m[:, 0]] == ids_def[m[:, 1]]
    common = np.intersect1d(ids_ref, ids_def).size
    xt = x_um[ids_ref[m[:, 0]]]
    truth = motion(xt) - xt
    raw = float(np.sqrt(np.mean(np.sum((result.displacement_um - truth) ** 2, axis=1)))) / s
    fld = float(np.sqrt(np.mean(np.sum((result.displacement_field(xt) - truth) ** 2, axis=1))))
    return int(good.sum()) / common, int((~good).sum()), raw, fld / s


def score_link(pair: SyntheticPair, matches, displacement_field=None) -> LinkScore:
    """Score links ``matches`` (K, 2) ``[row_ref, row_def]`` against the truth of ``pair``.

    Parameters
    ----------
    pair : SyntheticPair
    matches : array_like of int, shape (K, 2)
    displacement_field : callable, optional
        ``u(xyz_um (P, 3)) -> (P, 3)``, evaluated at the true reference positions of the
        linked particles.

    Returns
    -------
    LinkScore
    """
    m = np.asarray(matches, dtype=np.int64).reshape(-1, 2)
    s = pair.spacing_um
    ida, idb = pair.ref_ids[m[:, 0]], pair.def_ids[m[:, 1]]
    good = ida == idb
    common = pair.common_ids
    x = pair.seeds_um[ida]
    truth = pair.true_displacement_um[ida]
    d = pair.def_xyz_um[m[:, 1]] - pair.ref_xyz_um[m[:, 0]]
    err = d - truth
    sig2 = 2.0 * np.asarray(pair.noise_xyz_um) ** 2
    floor = np.where(
        good[:, None], (pair.def_noise_um[m[:, 1]] - pair.ref_noise_um[m[:, 0]]) ** 2, sig2
    )
    if m.shape[0]:
        excess = np.sqrt(np.sum(np.maximum(np.mean(err**2 - floor, axis=0), 0.0))) / s
        raw = tuple(float(v) for v in np.sqrt(np.mean(err**2, axis=0)) / s)
    else:
        excess, raw = float("nan"), (float("nan"),) * 3
    fld = (float("nan"),) * 3
    if displacement_field is not None and m.shape[0]:
        fe = np.asarray(displacement_field(x)) - truth
        fld = tuple(float(v) for v in np.sqrt(np.mean(fe**2, axis=0)) / s)
    b = pair.bounds_xyz_um
    pc = pair.seeds_um[common]
    near = np.min(np.minimum(pc - b[:, 0], b[:, 1] - pc), axis=1) <= s
    correct_ids = ida[good]
    n_face = int(near.sum())
    face = float(np.isin(common[near], correct_ids).mean()) if n_face else float("nan")
    return LinkScore(
        tracking_ratio=float(good.sum()) / max(common.size, 1),
        face_tracking_ratio=face,
        wrong_fraction=float((~good).sum()) / max(m.shape[0], 1),
        n_common=int(common.size),
        n_links=int(m.shape[0]),
        n_wrong=int((~good).sum()),
        n_face=n_face,
        excess_rmse_spacings=float(excess),
        raw_rmse_xyz_spacings=raw,
        field_rmse_xyz_spacings=fld,
    )


__all__ = ["LinkScore", "score_link", "score_motion"]
