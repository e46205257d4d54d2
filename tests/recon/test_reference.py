"""recon.reference: settings, the positions' checksum that drives resume, an empty frame."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lfsim.scene import read_optics
from recon.errors import InputError
from recon.reference import ReferenceSettings, positions_checksum, render_reference

SCENES = Path(__file__).resolve().parents[2] / "scenes"


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"sphere_diameter_um": 0}, "sphere_diameter_um"),
        ({"rays_per_particle": 0}, "rays_per_particle must be an integer >= 1"),
        ({"seed": -1}, "seed must be an integer >= 0"),
        ({"counts_per_ray": True}, "counts_per_ray"),
        ({"black_level": -1}, "black_level"),
    ],
)
def test_settings_are_checked(kwargs, message):
    with pytest.raises(InputError, match=message):
        ReferenceSettings(**kwargs)


def test_checksum_follows_positions_and_settings():
    p = np.array([[1.0, 2.0, 100.0], [3.0, 4.0, 200.0]])
    st = ReferenceSettings()
    assert positions_checksum(p, st) == positions_checksum(p.copy(), ReferenceSettings())
    assert positions_checksum(p, st) != positions_checksum(p + np.array([0, 0, 1e-9]), st)
    assert positions_checksum(p, st) != positions_checksum(p, ReferenceSettings(seed=6))


def test_empty_frame_is_the_black_level_and_bad_positions_are_refused():
    optics = read_optics(SCENES / "medium_glass.xml")  # modelled with ideal lenslets
    img = render_reference(np.zeros((0, 3)), optics, ReferenceSettings(black_level=7.0))
    assert img.shape == optics.sensor_xy_px[::-1] and img.dtype == np.float32 and np.all(img == 7.0)
    with pytest.raises(InputError, match=r"finite \(N, 3\)"):
        render_reference(np.array([[0.0, 0.0]]), optics)
