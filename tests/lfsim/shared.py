"""Values shared by the lfsim tests of the camera and the noise models."""

from __future__ import annotations

import numpy as np

from lfsim.camera import CameraModel

#: The largest value and the dtype of an image of each bit depth.
FULL = {8: 255, 12: 4095, 16: 65535}
DTYPE = {8: np.uint8, 12: np.uint16, 16: np.uint16}

#: A generic 12-bit camera (frozen: safe to share between tests).
CAM = CameraModel(
    quantum_efficiency=0.8,
    read_noise_e=2.0,
    gain_dn_per_e=0.5,
    offset_dn=100.0,
    bit_depth=12,
    full_well_e=10_000.0,
)
