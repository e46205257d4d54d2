"""Segmentation: thresholds, size / shape / clump / edge filters and the blob report."""

from __future__ import annotations

import numpy as np
import pytest

from track.errors import InputError
from track.segment import SegmentSettings, auto_threshold, segment

from .conftest import render_blobs

SIGMA = (2.5, 1.2, 1.2)
VOXEL = (5.0, 1.64, 1.64)
SHAPE = (48, 64, 64)
SINGLES = np.array(
    [[10 + 24 * (i // 4), 10 + 14 * (i % 4), 12 + 0.3 * i] for i in range(8)]
) + np.array([0.3, 0.2, 0.1])


#: The robust noise threshold and the wider automatic size window these scenes test (the
#: defaults are the paper's fraction 0.25 and (0.1, 3.0), see test_fraction_threshold_and_report)
AUTO = {"threshold": "auto", "auto_size_factors": (0.3, 3.0)}


def _segment(vol, edge_margin_vox=(0, 0, 0), **settings):
    return segment(
        vol, VOXEL, SegmentSettings(**{**AUTO, **settings}), edge_margin_vox=edge_margin_vox
    )


def _scene(rng, snr=50.0):
    """8 singles in a row plus a streak, a merged pair and an edge blob; returns labels."""
    vol = render_blobs(SHAPE, SINGLES, SIGMA)
    vol += render_blobs(SHAPE, [[24.2, 30.4, 47.0]], (2.5, 1.2, 7.0))  # streak along x
    pair = np.array([[36.3, 50.2, 45.0], [36.3, 50.2, 49.2]])  # 4.2 voxels apart along x
    vol += render_blobs(SHAPE, pair, SIGMA)
    vol += render_blobs(SHAPE, [[24.0, 45.0, 1.0]], SIGMA)  # cut by the x = 0 face
    vol += rng.normal(0.0, 1.0 / snr, SHAPE)
    return vol


def _blob_at(seg, point):
    lab = seg.labels[tuple(np.rint(point).astype(int))]
    assert lab > 0, f"no blob at {point}"
    return next(b for b in seg.blobs if b.label == lab)


def test_filters_keep_singles_and_reject_streak_pair_and_edge(rng):
    seg = _segment(_scene(rng))
    for c in SINGLES:
        b = _blob_at(seg, c)
        assert b.accepted, b.reason
        np.testing.assert_allclose(b.centroid_vox, c, atol=0.3)
    assert len(seg.accepted) == len(SINGLES)
    streak = _blob_at(seg, (24, 30, 47))
    assert not streak.accepted and ("elongated" in streak.reason or "large" in streak.reason)
    pair = _blob_at(seg, (36, 50, 47))
    assert not pair.accepted and ("clump" in pair.reason or "elongated" in pair.reason)
    edge = _blob_at(seg, (24, 45, 0))
    assert not edge.accepted and "edge" in edge.reason
    assert seg.counts["components"] >= 11 and seg.counts["clump"] == len(SINGLES)
    d = pair.as_dict()
    assert d["reason"] == pair.reason and len(d["bbox"]) == 6


def test_shape_filter_alone_rejects_streak_and_pair(rng):
    # generous explicit size limits: only the shape / clump tests can reject them
    seg = _segment(_scene(rng), blob_min_vox=5, blob_max_vox=100000)
    assert not _blob_at(seg, (24, 30, 47)).accepted
    assert "elongated" in _blob_at(seg, (24, 30, 47)).reason
    assert not _blob_at(seg, (36, 50, 47)).accepted
    assert all(_blob_at(seg, c).accepted for c in SINGLES)
    assert seg.size_bounds_vox == (5, 100000)


def test_clump_test_finds_two_maxima_in_merged_pair(rng):
    seg = _segment(_scene(rng), blob_min_vox=5, blob_max_vox=100000, max_rel_aspect=50)
    pair = _blob_at(seg, (36, 50, 47))
    assert pair.n_maxima == 2 and "clump" in pair.reason
    assert all(_blob_at(seg, c).n_maxima == 1 for c in SINGLES)


def test_edge_margin(rng):
    vol = _scene(rng)
    # singles sit 10 voxels (16.4 µm) from the y = 0 face: a 12-voxel margin rejects that row
    seg = _segment(vol, edge_margin_vox=(0, 12, 0))
    row = [c for c in SINGLES if c[1] < 12]
    assert row and all("edge" in _blob_at(seg, c).reason for c in row)


def test_auto_threshold_on_noisy_volume(rng):
    for snr in (15.0, 50.0):
        vol = _scene(rng, snr)
        thr = auto_threshold(vol)
        noise = 1.0 / snr
        assert 3 * noise < thr < 0.6  # above the noise, below the particle peaks
        seg = _segment(vol)
        assert len(seg.accepted) == len(SINGLES)
    # pure noise: nothing accepted
    noise_only = rng.normal(0.0, 1.0, SHAPE)
    assert _segment(noise_only).accepted == ()


def test_fraction_threshold_and_report():
    vol = render_blobs(SHAPE, SINGLES, SIGMA, background=0.2)
    seg = segment(vol, VOXEL)  # the default: the paper's 0.25 of the range
    assert seg.threshold == pytest.approx(vol.min() + 0.25 * (vol.max() - vol.min()))
    assert len(seg.accepted) == len(SINGLES)
    assert seg.labels.shape == SHAPE and seg.labels.dtype == np.int32
    assert np.all(np.isfinite(seg.reference_cov_um2))
    # the reference tensor is elongated along z (µm²), like the particles
    assert seg.reference_cov_um2[0, 0] > 4 * seg.reference_cov_um2[2, 2]
    assert SegmentSettings().threshold == 0.25
    empty = segment(np.zeros(SHAPE), VOXEL)
    assert empty.blobs == () and empty.accepted == ()


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"threshold": 1.5}, "threshold"),
        ({"threshold": True}, "threshold"),
        ({"auto_k_sigma": 0}, "auto_k_sigma"),
        ({"auto_size_factors": (2.0, 3.0)}, "auto_size_factors"),
        ({"auto_size_factors": (0.5,)}, "auto_size_factors"),
        ({"threshold": "otsu"}, "threshold"),
        ({"blob_min_vox": 0}, "blob_min_vox"),
        ({"blob_min_vox": 50, "blob_max_vox": 10}, "blob_min_vox"),
        ({"max_rel_aspect": 0.5}, "max_rel_aspect"),
        ({"max_rel_aspect": "wide"}, "max_rel_aspect"),
        ({"clump_prominence": 1.0}, "clump_prominence"),
    ],
)
def test_segment_settings_reject_bad_values(kwargs, name):
    with pytest.raises(InputError, match=name):
        SegmentSettings(**kwargs)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"edge_margin_vox": (1, 2)}, "edge_margin_vox"),
        ({"voxel_size_um": (0, 1, 1)}, "voxel_size_um"),
        ({"settings": {"threshold": 0.3}}, "SegmentSettings"),
    ],
)
def test_segment_rejects_bad_parameters(kwargs, name):
    args = {"voxel_size_um": VOXEL}
    args.update(kwargs)
    with pytest.raises(InputError, match=name):
        segment(np.zeros((8, 8, 8)), **args)
