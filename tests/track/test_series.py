"""Series of point clouds: trajectories and Eulerian cumulation (track.series)."""

from __future__ import annotations

from itertools import pairwise
from types import SimpleNamespace

import numpy as np
import pytest

from track.errors import InputError, TrackingError
from track.fields import GridSettings
from track.series import (
    SeriesSettings,
    cumulate_eulerian,
    lagrangian_displacements,
    link_tracks,
    track_series,
)
from track.strain import infinitesimal


def _shear(g):
    return np.array([[1.0, 0.0, g], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])


def _rot_y(deg):
    t = np.deg2rad(deg)
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _cloud(n=150, seed=11):
    return np.random.default_rng(seed).uniform([0, 0, 0], [200, 160, 120], (n, 3))


def _identity_linker(ref, dfm, settings, initial_guess=None):
    """Known matches: the clouds hold the same particles in the same rows."""
    n = ref.shape[0]
    return SimpleNamespace(
        matches=np.c_[np.arange(n), np.arange(n)],
        displacement_um=dfm - ref,
        tracking_ratio=1.0,
        iterations=1,
    )


def _series(increments, seed=11):
    clouds = [_cloud(seed=seed)]
    for F in increments:
        clouds.append(clouds[-1] @ F.T)  # homogeneous increment about the origin
    return clouds


def _product(increments):
    total = np.eye(3)
    for F in increments:
        total = F @ total  # F_total = F_inc · F_prev
    return total


SETTINGS = SeriesSettings(grid=GridSettings(target_nodes=2000))


def _rel_err(F, F_ref):
    return np.max(np.abs(F - F_ref)) / np.max(np.abs(F_ref - np.eye(3)))


@pytest.mark.parametrize(
    "increments",
    [
        [_shear(0.05)] * 10,
        [_rot_y(6.0) @ _shear(0.05) if k % 2 else _shear(0.05) @ _rot_y(-4.0) for k in range(10)],
    ],
    ids=["simple-shear", "rotation+shear"],
)
def test_eulerian_cumulation_matches_product_of_increments(increments):
    clouds = _series(increments)
    res = track_series(clouds, SETTINGS, linker=_identity_linker)
    assert all(p.ok for p in res.pairs) and set(res.field_status) == {"ok"}
    F_true = _product(increments)
    g = res.total_fields[-1]
    inner = g.mask.copy()
    inner[[0, -1], :, :] = inner[:, [0, -1], :] = inner[:, :, [0, -1]] = False
    assert inner.sum() > 100
    F = g.F[inner]
    assert _rel_err(F, F_true) < 0.005  # < 0.5 % of the applied deformation
    # total displacement: x(X) = F_true X for a homogeneous deformation about the origin
    X = np.stack(np.meshgrid(g.z_um, g.y_um, g.x_um, indexing="ij"), -1)[..., ::-1]
    assert np.allclose(g.u[inner], (X @ (F_true - np.eye(3)).T)[inner], atol=1e-6)
    assert np.allclose(g.e, infinitesimal(g.F))
    # The MATLAB bug: reversed composition or symmetrised increments give a different F.
    reversed_F = np.eye(3)
    sym_F = np.eye(3)
    for Fi in increments:
        reversed_F = reversed_F @ Fi
        sym_F = (np.eye(3) + infinitesimal(Fi)) @ sym_F
    wrong = [reversed_F, sym_F]
    errors = [_rel_err(F, W) for W in wrong]
    assert max(errors) > 0.05  # at least one bug is 10× beyond the tolerance
    if len({Fi.tobytes() for Fi in increments}) > 1:  # non-commuting increments
        assert min(errors) > 0.02


def test_cumulate_eulerian_function_and_displaced_evaluation():
    """Evaluating the increment at X (not x(X)) is wrong for non-uniform increments."""
    from track.fields import fit_displacement, grid_axes

    X0 = _cloud(seed=4)
    u1 = np.c_[0.1 * X0[:, 2], np.zeros(len(X0)), np.zeros(len(X0))]  # shear: x moves with z
    X1 = X0 + u1
    u2 = np.c_[np.zeros(len(X0)), 1e-3 * X1[:, 0] ** 2, np.zeros(len(X0))]  # depends on x
    ax = grid_axes(X0, 20.0)
    inc = [fit_displacement(X0, u1), fit_displacement(X1, u2)]
    tot = cumulate_eulerian(ax, inc)
    P = ax.points()
    x1 = P + np.c_[0.1 * P[:, 2], 0 * P[:, :2]]
    expect_uy = 1e-3 * x1[:, 0] ** 2
    m = tot[-1].mask.ravel()
    got = tot[-1].u.reshape(-1, 3)
    err_right = np.sqrt(np.mean((got[m, 1] - expect_uy[m]) ** 2))
    err_wrong = np.sqrt(np.mean((got[m, 1] - 1e-3 * P[m, 0] ** 2) ** 2))
    assert err_right < 0.1 * err_wrong
    assert err_right < 0.01 * np.max(np.abs(expect_uy))


def test_cumulation_from_the_gridded_increments_matches_the_spline():
    """The cumulation reads each increment at the displaced nodes from its gridded field
    (trilinear gradients, Taylor-corrected values) instead of evaluating the spline there:
    exact for the first increment, close to the spline for a curved one."""
    from track.fields import field_on_grid, fit_displacement, grid_axes
    from track.series import EulerianCumulation

    X0 = _cloud(seed=4)
    u1 = np.c_[0.1 * X0[:, 2], np.zeros(len(X0)), np.zeros(len(X0))]
    X1 = X0 + u1
    u2 = np.c_[np.zeros(len(X0)), 1e-3 * X1[:, 0] ** 2, np.zeros(len(X0))]
    ax = grid_axes(X0, 20.0)
    inc = [fit_displacement(X0, u1), fit_displacement(X1, u2)]
    exact = cumulate_eulerian(ax, inc)
    cum = EulerianCumulation(ax)
    fast = [cum.add(i, field_on_grid(i, ax)) for i in inc]
    assert np.allclose(fast[0].u, exact[0].u, rtol=0, atol=1e-12)
    assert np.allclose(fast[0].F, exact[0].F, rtol=0, atol=1e-12)
    # Against the truth u_y = 1e-3 x², x = X + 0.1 Z: as close as the spline itself
    # (measured: u_y RMS error 0.111 vs 0.096 µm, ∂u_y/∂X 0.0118 vs 0.0118).
    m = exact[-1].mask.ravel()
    P = ax.points()
    x = P[m, 0] + 0.1 * P[m, 2]
    for axis, true in ((None, 1e-3 * x**2), (0, 2e-3 * x), (2, 2e-4 * x)):
        errs = []
        for f in (exact[1], fast[1]):
            got = f.u.reshape(-1, 3)[m, 1] if axis is None else f.F.reshape(-1, 3, 3)[m, 1, axis]
            errs.append(np.sqrt(np.mean((got - true) ** 2)))
        assert errs[1] < 1.25 * errs[0], (axis, errs)


def test_lagrangian_tracks_persist_through_increments():
    # frame sizes 5, 6, 4 with known matches
    m1 = np.array([[0, 3], [1, 0], [2, 1], [4, 5]])  # particle 3 of frame 0 is lost
    m2 = np.array([[3, 0], [0, 2], [5, 3]])  # rows of frame 1 -> frame 2
    t = link_tracks([5, 6, 4], [m1, m2])
    ids = {f: t.track_id[t.frame == f] for f in range(3)}
    assert list(ids[0]) == [0, 1, 2, 3, 4]
    assert list(ids[1][[3, 0, 1, 5]]) == [0, 1, 2, 4]
    new = sorted(set(ids[1]) - {0, 1, 2, 4})
    assert new == [5, 6]
    assert ids[2][0] == 0 and ids[2][2] == 1 and ids[2][3] == 4  # through two increments
    assert ids[2][1] not in set(ids[1])
    assert len(set(t.track_id[t.frame == 2])) == 4
    # a skipped increment breaks every track
    t2 = link_tracks([3, 3, 3], [None, np.c_[[0, 1, 2], [0, 1, 2]]])
    assert set(t2.track_id[t2.frame == 1]).isdisjoint(range(3))
    with pytest.raises(TrackingError, match="used twice"):
        link_tracks([3, 3], [np.array([[0, 1], [1, 1]])])


def test_tracks_in_series_follow_known_permutation():
    rng = np.random.default_rng(2)
    base = _cloud(60)
    perms = [np.arange(60), rng.permutation(60), rng.permutation(60)]
    clouds = [base[p] + 0.5 * k for k, p in enumerate(perms)]

    def linker(ref, dfm, settings, initial_guess=None):
        # match by nearest position (displacement 0.5 µm is tiny versus spacing)
        d = np.linalg.norm(ref[:, None] - dfm[None], axis=2)
        j = d.argmin(axis=1)
        return SimpleNamespace(
            matches=np.c_[np.arange(len(ref)), j],
            displacement_um=dfm[j] - ref,
            tracking_ratio=1.0,
            iterations=1,
        )

    res = track_series(clouds, SeriesSettings(compute_fields=False), linker=linker)
    tr = res.tracks
    for k in (1, 2):
        sel = tr.frame == k
        # row r of frame k is particle perms[k][r] of frame 0, whose track id is its row
        assert np.array_equal(tr.track_id[sel][np.argsort(tr.row[sel])], perms[k])
    assert res.field_status == ("skipped: fields not requested",) * 2
    tid, x0, u = lagrangian_displacements(tr, 2)
    assert np.array_equal(tid, np.arange(60))
    assert np.allclose(x0, base) and np.allclose(u, 1.0)


def test_cumulative_mode_links_to_frame_zero_and_passes_a_guess():
    inc = [_shear(0.05)] * 3
    clouds = _series(inc)
    calls = []

    def linker(ref, dfm, settings, initial_guess=None):
        calls.append(initial_guess)
        r = _identity_linker(ref, dfm, settings)
        r.displacement_field = lambda p: p * 0
        return r

    res = track_series(
        clouds,
        SeriesSettings(mode="cumulative", grid=GridSettings(target_nodes=1500)),
        linker=linker,
    )
    assert [p.ref_frame for p in res.pairs] == [0, 0, 0]
    assert calls[0] is None and callable(calls[1])
    g = res.total_fields[-1]
    assert _rel_err(g.F[g.mask], _product(inc)) < 1e-6
    assert res.increment_fields == (None, None, None)


def test_frame_with_too_few_particles_is_flagged_not_extrapolated():
    clouds = _series([_shear(0.02)] * 3)
    clouds[2] = clouds[2][:3]
    res = track_series(clouds, SETTINGS, linker=_identity_linker)
    st = [p.status for p in res.pairs]
    assert st[0] == "ok"
    assert st[1].startswith("skipped: fewer than 4 particles in frame 2")
    assert st[2].startswith("skipped: fewer than 4 particles in frame 2")
    assert res.field_status[0] == "ok"
    assert res.field_status[1].startswith("skipped")
    assert res.field_status[2].startswith("skipped")
    assert res.total_fields[1] is None and res.total_fields[2] is None


def test_failed_linking_is_flagged():
    def linker(ref, dfm, settings, initial_guess=None):
        return SimpleNamespace(ok=False, reason="bootstrap failed", matches=np.zeros((0, 2), int))

    res = track_series(_series([_shear(0.02)]), SETTINGS, linker=linker)
    assert res.pairs[0].status == "skipped: tracking failed: bootstrap failed"
    assert np.isnan(res.pairs[0].tracking_ratio)


def test_bad_inputs():
    with pytest.raises(InputError, match="mode"):
        SeriesSettings(mode="lagrangian")
    with pytest.raises(InputError, match="at least 2 frames"):
        track_series([_cloud()], linker=_identity_linker)
    c = _cloud()
    c[3, 2] = np.nan
    with pytest.raises(InputError, match="frame 1"):
        track_series([_cloud(), c], linker=_identity_linker)


def test_series_fields_carry_uncertainties():
    """Increment fields carry their propagated σ; the Eulerian total adds the increments'
    variances (first total = first increment; later totals never smaller), the settings can
    turn them off."""
    rng = np.random.default_rng(3)
    clouds = [c + rng.normal(0, [0.3, 0.3, 3.0], c.shape) for c in _series([_shear(0.02)] * 3)]
    res = track_series(clouds, SETTINGS, linker=_identity_linker)
    inc, tot = res.increment_fields, res.total_fields
    assert all(f.u_std is not None and f.e_std is not None for f in (*inc, *tot))
    assert np.allclose(tot[0].u_std, inc[0].u_std) and np.allclose(tot[0].F_std, inc[0].F_std)
    assert np.all(tot[2].u_std >= tot[1].u_std) and np.all(tot[1].u_std >= tot[0].u_std)
    # about √3 × one increment's after three similar increments (measured 1.68 median)
    ratio = np.median(tot[2].u_std[tot[2].mask] / inc[0].u_std[tot[2].mask])
    assert 1.5 < ratio < 2.0, ratio
    off = SeriesSettings(grid=GridSettings(target_nodes=2000, uncertainty=False))
    res = track_series(clouds, off, linker=_identity_linker)
    assert res.total_fields[-1].u_std is None and res.increment_fields[0].e_std is None


def test_match_sigma_holds_the_moving_bias_of_the_settings():
    """The per-match σ that ``track`` writes holds the settings' moving-bias term (the one
    the study reports check coverage with), and only the random parts without it."""
    from dataclasses import replace

    from track.series import match_sigma

    clouds = _series([_shear(0.02)] * 2)
    sig = [np.tile([0.2, 0.2, 2.0], (len(c), 1)) for c in clouds]
    biased = replace(SETTINGS, bias_sigma_um=(1.5, 0.1, 0.1), bias_length_um=(5.0, 2.5, 2.5))
    for settings, bias in ((SETTINGS, None), (biased, (0.1, 0.1, 1.5))):
        pair = track_series(clouds, settings, linker=_identity_linker, sigmas=sig).pairs[0]
        want = match_sigma(
            pair.matches,
            sig[0],
            sig[1],
            displacement_um=pair.displacement_um,
            bias_sigma_xyz_um=bias,
            bias_length_xyz_um=(2.5, 2.5, 5.0),
        )
        assert np.allclose(pair.sigma_displacement_xyz_um, want)
    assert np.median(want[:, 2]) > np.hypot(2.0, 2.0) + 0.05  # moved particles: bias adds


#: Detections (x, y, z µm) of frames 10–13 of the paper-size Fig. 5b study (a layer of 20
#: particles moving 20 µm along z per frame; glass lenslets rendered, ideal reconstructed,
#: 3 RL iterations on 5 µm), rounded to 1 nm: (frame, x, y, z).
_LAYER_FRAMES = (
    (0, -423.750, -373.136, 355.670),
    (0, -586.573, -460.396, 356.604),
    (0, 30.652, -422.502, 355.888),
    (0, -88.255, -402.692, 355.922),
    (0, 545.301, -339.081, 355.920),
    (0, 176.584, -263.898, 355.631),
    (0, -563.247, -261.763, 356.127),
    (0, 852.377, -207.094, 355.585),
    (0, 622.494, -99.927, 354.899),
    (0, -417.263, -16.267, 356.352),
    (0, 17.889, 11.890, 355.295),
    (0, -874.691, 31.742, 355.252),
    (0, 525.908, 124.376, 357.316),
    (0, -831.622, 155.594, 356.690),
    (0, 877.159, 247.158, 355.907),
    (0, -897.405, 278.914, 355.863),
    (0, -323.424, 317.146, 355.151),
    (0, -668.755, 351.689, 355.491),
    (0, 686.399, 414.111, 356.569),
    (0, 22.391, 495.404, 355.911),
    (1, 686.399, 414.078, 372.133),
    (1, -586.583, -460.373, 373.044),
    (1, 30.485, -422.549, 376.871),
    (1, -88.331, -402.540, 375.369),
    (1, 545.376, -339.180, 374.886),
    (1, -563.373, -261.599, 373.164),
    (1, 176.678, -263.765, 375.644),
    (1, 622.555, -99.873, 377.845),
    (1, -417.133, -16.119, 374.579),
    (1, 17.945, 12.015, 374.051),
    (1, -874.834, 31.398, 377.685),
    (1, 525.774, 124.343, 377.836),
    (1, -831.645, 155.498, 375.615),
    (1, -323.475, 317.227, 376.429),
    (1, -668.860, 351.693, 377.837),
    (1, 22.446, 495.497, 376.811),
    (1, -423.916, -373.226, 379.941),
    (1, 852.572, -207.114, 376.729),
    (1, 877.275, 247.385, 376.991),
    (1, -897.674, 278.824, 379.608),
    (2, -586.481, -460.145, 392.641),
    (2, -563.557, -261.476, 392.255),
    (2, 30.471, -422.404, 396.148),
    (2, -88.373, -402.481, 395.233),
    (2, 545.437, -339.150, 395.368),
    (2, 176.520, -263.884, 395.511),
    (2, 622.580, -99.802, 398.017),
    (2, -417.218, -16.172, 393.441),
    (2, 18.027, 11.911, 392.932),
    (2, 525.810, 124.248, 398.234),
    (2, -831.422, 155.397, 395.699),
    (2, -323.619, 317.318, 396.936),
    (2, -669.029, 351.598, 396.678),
    (2, 686.453, 414.256, 393.347),
    (2, 22.360, 495.523, 396.628),
    (2, -423.946, -373.325, 398.397),
    (2, 852.370, -206.868, 397.418),
    (2, -874.627, 31.390, 399.004),
    (2, 877.150, 247.255, 398.098),
    (2, -897.617, 278.938, 398.047),
    (3, -563.326, -261.516, 413.833),
    (3, 686.284, 414.097, 414.765),
    (3, -586.446, -460.158, 414.127),
    (3, 30.415, -422.550, 414.978),
    (3, -88.392, -402.430, 415.075),
    (3, -424.058, -373.141, 415.708),
    (3, 545.690, -339.353, 416.046),
    (3, 176.531, -263.957, 415.608),
    (3, 852.305, -206.967, 416.236),
    (3, 622.700, -99.817, 415.837),
    (3, -417.360, -16.408, 414.427),
    (3, 17.965, 12.003, 415.328),
    (3, -874.777, 31.335, 414.638),
    (3, 525.768, 124.394, 414.921),
    (3, -831.470, 155.317, 415.872),
    (3, 877.191, 247.363, 415.425),
    (3, -897.510, 278.803, 415.776),
    (3, -323.491, 317.420, 414.924),
    (3, -669.114, 351.417, 414.645),
    (3, 22.508, 495.516, 415.770),
)


def test_a_thin_layer_moving_along_z_stays_tracked_when_the_predictor_misleads():
    """The previous increment's field, fitted on a layer 8 µm thick and evaluated 20 µm
    above it, starts a consistent but partial set (8 of 20) that growth cannot complete
    (frames 11 → 12 of the paper-size 5b layer: 6 of the 20 particles linked from the guess
    alone). So the bootstrap runs as well when the guess links fewer than
    ``guess_confirm_fraction`` of the particles, and the better result is kept."""
    from track.series import SeriesSettings, link_pairs

    data = np.array(_LAYER_FRAMES)
    clouds = [data[data[:, 0] == k, 1:] for k in range(4)]
    res = link_pairs(clouds, SeriesSettings())
    assert [r.matches.shape[0] for r in res] == [20, 20, 20]
    for r in res:  # every match is the layer's 20 µm step (z noise of a few µm)
        u = r.displacement_um
        assert np.all(np.abs(u[:, :2]) < 2.0) and np.all(np.abs(u[:, 2] - 20.0) < 8.0)


def _track_truth(tracks, frame_ids):
    """Per track ``{frame: particle id}``, and the number of consecutive rows of a track that
    hold different particles (wrong links)."""
    out, wrong = {}, 0
    for t in np.unique(tracks.track_id):
        sel = tracks.track_id == t
        o = np.argsort(tracks.frame[sel])
        fr = tracks.frame[sel][o].tolist()
        p = [int(frame_ids[f][r]) for f, r in zip(fr, tracks.row[sel][o], strict=True)]
        wrong += sum(a != b for a, b in pairwise(p))
        out[int(t)] = dict(zip(fr, p, strict=True))
    return out, wrong


def _ratios(truth, frame_ids):
    """Per frame k ≥ 1: particles tracked right from frame 0 / particles in both frames."""
    out = []
    for k in range(1, len(frame_ids)):
        both = np.intersect1d(frame_ids[0], frame_ids[k]).size
        ok = sum(1 for m in truth.values() if 0 in m and k in m and m[0] == m[k])
        out.append(ok / both)
    return np.array(out)


def test_particles_missed_in_intermediate_frames_keep_their_tracks():
    """A particle the detector misses in one or two intermediate frames keeps its track:
    tracks are bridged over such gaps from the tracks around them. Without bridging, the
    paper-size inclusion_stretch links all but one of the particles detected in both frames
    of each increment, yet its tracking ratio against frame 0 falls frame by frame (107 →
    100 of 108, 0.926), each missed particle ending its track and coming back as a new
    one (``SeriesSettings(bridge_tracks=False)``, ``track run --no-bridge``)."""
    from track.synthetic import make_series

    s = make_series("stiff_inclusion", 400, 0.5, 6, seed=1, drop_fraction=0.08)
    clouds = list(s.frames_xyz_um)
    res = track_series(clouds, SeriesSettings(compute_fields=False))
    truth, wrong = _track_truth(res.tracks, s.frame_ids)
    assert wrong == 0
    assert np.all(_ratios(truth, s.frame_ids) >= 0.99)
    gaps = [np.diff(sorted(m)) for m in truth.values()]
    assert sum(int(np.sum(g == 2)) for g in gaps) >= 20  # one frame missed
    assert sum(int(np.sum(g == 3)) for g in gaps) >= 2  # two frames in a row
    # without bridging (the same pairs) the chain loses every particle missed once
    off = SeriesSettings(compute_fields=False, bridge_tracks=False)
    old = track_series(clouds, off, pairs=res.pairs)
    old_truth, old_wrong = _track_truth(old.tracks, s.frame_ids)
    assert old_wrong == 0 and _ratios(old_truth, s.frame_ids)[-1] < 0.8
    # a gap longer than max_gap_frames is not bridged
    one = SeriesSettings(compute_fields=False, max_gap_frames=1)
    short, _ = _track_truth(track_series(clouds, one, pairs=res.pairs).tracks, s.frame_ids)
    assert all(np.all(np.diff(sorted(m)) <= 2) for m in short.values())


def test_a_particle_its_pair_left_unmatched_is_bridged_but_not_across_a_skipped_pair():
    rng = np.random.default_rng(4)
    x0 = _cloud(120, seed=4)
    F = np.array([[1.04, 0.0, 0.0], [0.0, 0.98, 0.0], [0.0, 0.0, 0.98]])
    clouds = [x0, x0 @ F.T, x0 @ F.T @ F.T]
    clouds = [c + rng.normal(0, [0.2, 0.2, 1.0], c.shape) for c in clouds]
    n = [len(c) for c in clouds]
    full = np.c_[np.arange(120), np.arange(120)]
    dropped = full[3:]  # the pair 0 → 1 left particles 0, 1, 2 unmatched
    t = link_tracks(n, [dropped, full], positions_um=clouds, max_gap_frames=0)
    for f in (1, 2):
        assert np.array_equal(t.track_id[t.frame == f], np.arange(120))
    # without bridging, or across a skipped pair, they start new tracks
    for ms, gap in (([dropped, full], None), ([None, full], 2)):
        t = link_tracks(n, ms, positions_um=clouds, max_gap_frames=gap)
        assert set(t.track_id[t.frame == 2][:3].tolist()).isdisjoint(range(120))
    with pytest.raises(InputError, match="max_gap_frames"):
        link_tracks(n, [full, full], positions_um=clouds, max_gap_frames=-1)
    with pytest.raises(InputError, match="max_gap_frames"):
        SeriesSettings(max_gap_frames=1.5)
    with pytest.raises(InputError, match="bridge_tracks"):
        SeriesSettings(bridge_tracks="yes")


def test_a_total_field_is_not_changed_by_the_next_increment():
    """Each total field keeps its own arrays: composing the next increment (which loses the
    support of some nodes) leaves the one returned before as it was, for the writer threads
    that may still be writing its files (track.pipeline)."""
    from track.fields import field_on_grid, fit_displacement, grid_axes
    from track.series import EulerianCumulation

    X0 = _cloud(seed=4)
    X1 = X0 + np.c_[0.1 * X0[:, 2], np.zeros((len(X0), 2))]
    half = X1[:, 0] < np.median(X1[:, 0])  # the second increment sees half the particles
    ax = grid_axes(X0, 20.0)
    inc = [
        fit_displacement(X0, X1 - X0),
        fit_displacement(X1[half], np.full((half.sum(), 3), 0.5)),
    ]
    cum = EulerianCumulation(ax)
    first = cum.add(inc[0], field_on_grid(inc[0], ax))
    kept = {k: np.array(getattr(first, k), copy=True) for k in ("u", "F", "E", "mask")}
    second = cum.add(inc[1], field_on_grid(inc[1], ax))
    assert second.mask.sum() < first.mask.sum()  # support was lost ...
    for k, v in kept.items():  # ... in the second field only
        np.testing.assert_array_equal(getattr(first, k), v, err_msg=k)


def test_the_incremental_predictor_scales_the_last_step_by_the_frame_intervals():
    """Frames at times 0, 1 and 3 (e.g. camera frames 0, 1, 3): the second increment spans
    twice the time of the first, so the constant-velocity guess is twice its displacement."""
    from track.series import link_pairs

    clouds = _series([np.eye(3)] * 3)
    guesses = []

    def linker(ref, dfm, settings, initial_guess=None):
        guesses.append(initial_guess)
        r = _identity_linker(ref, dfm, settings)
        r.displacement_field = lambda p: np.ones_like(p)  # 1 µm per increment
        return r

    p = np.zeros((1, 3))
    link_pairs(clouds, SeriesSettings(), linker=linker, frame_times=[0.0, 1.0, 3.0, 4.0])
    assert guesses[0] is None
    np.testing.assert_allclose(guesses[1](p), 2.0)
    np.testing.assert_allclose(guesses[2](p), 0.5)
    guesses.clear()
    link_pairs(clouds, SeriesSettings(), linker=linker)  # evenly spaced: the step repeated
    np.testing.assert_allclose(guesses[1](p), 1.0)
    with pytest.raises(InputError, match="frame_times must be 4 increasing"):
        link_pairs(clouds, SeriesSettings(), linker=linker, frame_times=[0.0, 1.0, 1.0, 2.0])
