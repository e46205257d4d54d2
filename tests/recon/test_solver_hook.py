"""The solver extension point of :func:`recon.pipeline.reconstruct_series`."""

from __future__ import annotations

import json

import numpy as np
import tifffile

CALLS: list[dict] = []
MARK = 7.25  # the value the custom solver writes into every voxel


class _Result:
    def __init__(self, volume, iterations):
        self.volume = volume
        self.iterations = iterations
        self.rel_change = [0.0]


def constant_solver(image, projector, iterations, **kwargs):
    """A trivial RL variant: a constant volume of the projector's shape."""
    CALLS.append({"image_shape": np.shape(image), "iterations": iterations, **kwargs})
    return _Result(np.full(projector.volume_shape, MARK, np.float32), 1)


def test_a_custom_solver_is_called_and_its_volume_is_written(backend, tmp_path):
    from lfsim import small_optics
    from lfsim.io import read_tiff
    from recon.calibration import LensletGrid
    from recon.pipeline import ReconSettings, reconstruct_series

    optics = small_optics()
    grid = LensletGrid(15.0, 0.0, tuple(optics.axis_xy_px), (300, 300))
    frame = tmp_path / "frame.tif"
    tifffile.imwrite(frame, np.full((300, 300), 100, np.uint16))
    settings = ReconSettings(
        z_min_um=-20, z_max_um=20, z_step_um=20, s=1, iterations=3, rays_per_pattern=5_000
    )
    CALLS.clear()
    common = dict(optics=optics, grid=grid, settings=settings, progress=False)
    res = reconstruct_series([frame], tmp_path / "vol", solver=constant_solver, **common)
    assert res.done == [0] and len(CALLS) == 1
    call = CALLS[0]
    assert call["iterations"] == 3  # the settings reach the solver
    assert set(call) >= {"depth_filter", "stop_rel_change", "track_kl", "background"}
    vol, _ = read_tiff(tmp_path / "vol" / "000000.tif")
    assert vol.shape[0] == 3 and np.all(vol == np.float32(MARK))  # its volume is the output
    record = json.loads((tmp_path / "vol" / "recon.json").read_text())
    assert record["frames"][0]["iterations"] == 1  # its iteration count is recorded
    # the default solver (Richardson–Lucy) gives another volume and another fingerprint
    ref = reconstruct_series([frame], tmp_path / "rl", **common)
    assert ref.done == [0] and len(CALLS) == 1
    rl, _ = read_tiff(tmp_path / "rl" / "000000.tif")
    assert not np.allclose(rl, MARK)
    assert (
        json.loads((tmp_path / "rl" / "recon.json").read_text())["fingerprint"]
        != record["fingerprint"]
    )
