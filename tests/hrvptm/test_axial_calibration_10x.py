"""``hrvptm axial`` on another microscope than the paper's (the self-calibration
transfers): the 10×/0.3 of the detection sweep (150 µm f/16.7 lenslets, 11 px per lenslet),
glass lenslets rendered, the ideal-lenslet model reconstructed and calibrated."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial import cKDTree

from track.tables import read_points_csv

from ..helpers import experiment_toml
from ..track.test_detect_settings import SWEEP
from .test_calibrated_cli import _errors, run

#: The sweep's 10× microscope on an 18 × 18-lenslet sensor (198 × 198 px).
TEN = SWEEP.microscopes(n_lenslets=18)["10x"]
FRAMES = 2
EXPERIMENT = experiment_toml(
    experiment={"name": "ten_axial", "scene": "{scene}", "seed": 4, "frames": FRAMES},
    particles={
        "kind": "box",
        "count": 8,
        "bounds_xyz_um": ((-110, 100), (-110, 100), TEN.z_particles_um),
        "min_spacing_um": 45,
        "diameter_um": TEN.particle_um,
    },
    motion={"type": "translation", "step_um": (2.0, 0.0, 0.0)},
    render={"rays_per_particle": 30000},
    noise={"model": "gaussian", "snr": 30},
    white={"rays_per_lenslet": 3000},
)
z0, z1 = TEN.z_volume_um
RECON = ["--z-range", f"{z0:g}:{z1:g}", "--z-step", "2", "-s", "8", "--iterations", "5"]


@pytest.mark.slow
@pytest.mark.studies
def test_self_calibration_on_a_10x_microscope(backend, tmp_path, capsys):
    """8 particles of 6 µm at z 60–110 µm (seed 4), 2 frames, reconstructed on 2 µm planes
    over z 20–150 µm with s = 8 and 5 RL iterations. Measured (seed 4): z position RMS error
    1.196 → 0.317 µm, x 0.201 → 0.057, y 0.099 → 0.091 µm; every particle found, nothing
    spurious (seeds 1 and 2: z 1.78 → 0.35 and 1.30 → 0.26 µm). The bounds: z at most 0.5 µm
    and 0.4× the raw error, x and y not 10 % worse. The size of the by-hand check (not scaled
    down): 80–100 s on 2 loaded cores (75 CPU s), most of it the PSF bank."""
    from lfsim.dataset import generate_dataset
    from lfsim.experiment import load_experiment
    from lfsim.scene import write_scene
    from recon.cli import main as recon

    scenes = {k: tmp_path / f"ten_{k}.xml" for k in ("ideal", "glass")}
    for kind, path in scenes.items():
        write_scene(replace(TEN.optics, mla_kind=kind), path)
    toml = tmp_path / "exp.toml"
    toml.write_text(EXPERIMENT.format(scene=scenes["glass"].as_posix()), "utf-8")
    ds = tmp_path / "ds"
    generate_dataset(load_experiment(toml), ds, progress=False)
    vol = tmp_path / "vol"
    rc = recon(["-q", "run", str(ds), "--scene", str(scenes["ideal"]), *RECON, "-o", str(vol)])
    assert rc == 0, capsys.readouterr().err
    out = tmp_path / "res"
    rc, _, err = run(capsys, "axial", vol, "-o", out, "--sphere-diameter-um", TEN.particle_um)
    assert rc == 0, err
    tables = {
        name: [out / name / "particles" / f"{k:06d}.csv" for k in range(FRAMES)]
        for name in ("detect", "axial")
    }
    # Every particle found once, nothing else (the particles are >= 45 µm apart).
    for k in range(FRAMES):
        truth = read_points_csv(ds / "truth" / f"{k:06d}.csv")
        for name, paths in tables.items():
            dist, idx = cKDTree(truth).query(read_points_csv(paths[k]))
            assert sorted(idx) == list(range(len(truth))), (name, k, idx)
            assert dist.max() < 10.0, (name, k, dist)
    rms_raw, rms_fixed = (
        np.sqrt(np.mean(_errors(ds / "truth", paths) ** 2, axis=0)) for paths in tables.values()
    )
    numbers = f"raw {rms_raw.round(3)}, corrected {rms_fixed.round(3)} µm (x, y, z)"
    assert rms_raw[2] > 0.9, numbers  # the reconstruction's axial bias is there
    assert rms_fixed[2] < 0.5 and rms_fixed[2] < 0.4 * rms_raw[2], numbers
    assert np.all(rms_fixed[:2] < 1.1 * rms_raw[:2]), numbers
    record = json.loads((out / "axial" / "axial_calibration.json").read_text("utf-8"))
    assert record["settings"]["sphere_diameter_um"] == TEN.particle_um
    assert [f["applied_axes"] for f in record["frames"]] == ["xyz"] * FRAMES
    assert [f["corrected"] for f in record["frames"]] == [8] * FRAMES
