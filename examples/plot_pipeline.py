"""
Simulate, reconstruct, track, strain
====================================

The whole chain on the demo's simple-shear experiment (test size: 24 particles, five
frames, the paper's optics on a small sensor), one library call per stage:

1. :func:`lfsim.generate_dataset` renders the light-field frames (through the glass
   microlens array) and a white image, with the true particle positions;
2. :func:`recon.calibrate_white` finds the lenslets and :func:`recon.reconstruct_series`
   turns each frame into a volume (ideal-lenslet model, as for real data);
3. :func:`track.track_volumes` detects, links and grids the particles into displacement and
   strain fields.

``hrvptm demo -o out/demo`` runs the same study with the comparison against the truth.
"""

# %%
# The experiment
# --------------
# A study file is an lfsim experiment with ``[study]``, ``[recon]`` and ``[track]`` sections.
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import tifffile

import hrvptm
import lfsim
import recon
import track
from lfsim.scene import read_optics
from recon.calibration_file import read_white

ROOT = Path(hrvptm.__file__).resolve().parents[1]
study = hrvptm.load_study(ROOT / "scenes" / "experiments" / "demo_simple_shear.toml")
work = Path(tempfile.mkdtemp())
print(study.study.kind, study.experiment.frames, "frames")

# %%
# 1. Simulate
# -----------
dataset = lfsim.generate_dataset(study.experiment, work / "dataset", progress=False)
frames = sorted((dataset / "frames").glob("[0-9]*.tif"))
image = tifffile.imread(frames[0])
fig, ax = plt.subplots(figsize=(6, 4))
ax.imshow(image, cmap="gray")
ax.set_title("light-field frame 0 (camera pixels)")
fig.tight_layout()

# %%
# 2. Reconstruct
# --------------
# The reconstruction uses the ideal lenslets of the same optics (``recon_scene``).
optics = read_optics(study.recon_scene)
white = read_white(dataset / "white.tif")
grid = recon.calibrate_white(white, expected_pitch_px=optics.px_per_lenslet)
volumes = work / "volumes"
recon.reconstruct_series(
    frames, volumes, optics=optics, grid=grid, settings=study.recon, progress=False
)
vol = tifffile.imread(volumes / "000000.tif")  # (z, y, x)
fig, ax = plt.subplots(figsize=(6, 4))
ax.imshow(vol.max(axis=0), cmap="magma")
ax.set_title(f"volume 0, maximum along z ({vol.shape[0]} planes)")
fig.tight_layout()

# %%
# 3. Track and strain
# -------------------
# The study's detection and series settings; the results folder is what ``track run`` writes.
results = work / "track"
track.track_volumes(
    volumes, results, detect=study.track.detect, series=study.track.series, progress=False
)
tracks = track.read_tracks(results)
fields = track.read_fields(results)
print(f"{tracks['track_id'].nunique()} tracks")

# %%
# The imposed motion is a simple shear ``u_x = γ (z − 250 µm)`` with γ growing 5 % a frame:
# the gridded ``E_xz`` of each frame against ``γ / 2`` (Green–Lagrange, small rotation
# terms aside).
inside = fields[fields["mask"]]
per_frame = inside.groupby("frame")["E_xz"].median()
gamma = 0.05 * per_frame.index.to_numpy()
fig, ax = plt.subplots(figsize=(5, 3.5))
ax.plot(per_frame.index, per_frame.to_numpy(), "o-", label="measured (median over the grid)")
ax.plot(per_frame.index, gamma / 2, "k--", label="γ / 2")
ax.set_xlabel("frame")
ax.set_ylabel("E_xz")
ax.legend()
fig.tight_layout()
print(np.round(per_frame.to_numpy(), 4))
assert np.allclose(per_frame.to_numpy(), gamma / 2, atol=0.01)  # the build fails on a regression
