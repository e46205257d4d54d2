"""The linker extension point of :func:`track.pipeline.track_volumes`."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

import track
from track.fields import GridSettings
from track.matching import LinkSettings, link_pair
from track.pipeline import track_volumes
from track.series import SeriesSettings

from .test_cli import _volumes


def _reversed(n_ref: int, n_def: int) -> np.ndarray:
    m = min(n_ref, n_def)
    return np.column_stack([np.arange(m), np.arange(m)[::-1]])


def test_a_custom_linker_is_called_and_its_matches_are_the_output(tmp_path):
    calls = []

    def reversed_linker(ref_xyz, def_xyz, link_settings, initial_guess=None):
        """A trivial linker: row i of one frame is row m − 1 − i of the next (m the smaller
        count), whatever the positions; no real linker pairs them so."""
        calls.append((ref_xyz.shape, def_xyz.shape, link_settings))
        matches = _reversed(len(ref_xyz), len(def_xyz))
        return SimpleNamespace(
            matches=matches,
            displacement_um=def_xyz[matches[:, 1]] - ref_xyz[matches[:, 0]],
            tracking_ratio=len(matches) / len(ref_xyz),
            iterations=1,
        )

    vols = tmp_path / "vols"
    _volumes(vols)
    link = LinkSettings(seed=3)
    series = SeriesSettings(grid=GridSettings(spacing_um=4.0), compute_fields=False, link=link)
    det = track.DetectSettings(deconvolution_iterations=0)
    res = track_volumes(vols, tmp_path / "res", detect=det, series=series, linker=reversed_linker)
    assert len(calls) == 2  # one call per pair of the 3 frames
    assert all(c[2] == link for c in calls)  # it gets the series' link settings
    for p in res.pairs:
        ref = res.frames[p.ref_frame].positions_um
        dfm = res.frames[p.def_frame].positions_um
        want = _reversed(len(ref), len(dfm))
        assert np.array_equal(p.matches, want)
        assert np.allclose(p.displacement_um, dfm[want[:, 1]] - ref[want[:, 0]])
    # the default linker pairs the frames otherwise (their 1.5 µm x steps): the output
    # above is the custom linker's
    ref, dfm = (res.frames[k].positions_um for k in (0, 1))
    default = link_pair(ref, dfm, link)
    assert not np.array_equal(default.matches, res.pairs[0].matches)
    assert np.allclose(np.median(default.displacement_um, axis=0), [1.5, 0, 0], atol=0.1)
