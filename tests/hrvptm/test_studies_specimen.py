"""Long tier: the paper's studies in the paper's specimen, a gel of index 1.35 on a 170 µm glass
bottom under the dry 4×/0.2 objective (scenes/medium_gel*.xml), end to end at test size.

The frames are rendered through the specimen's interfaces (exact refraction, glass lenslets)
and reconstructed with the specimen in the ideal-lenslet model, so positions, displacements and
strains are in true specimen depth. A true axial distance looks 0.736× as long through the gel,
so an axial error of the reconstruction is 1.36× larger in true µm than in air. The particles
lie at least 150 µm of apparent depth beyond the native plane (the focus rule of
docs/real_data.md). The z bounds are 1.5× the values measured on these files (5b: worst step
1.79 µm, 6c: 4.09 µm; their air studies 1.72 and 2.46 µm).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hrvptm.cli import main

EXPERIMENTS = Path(__file__).resolve().parents[2] / "scenes" / "experiments"

pytestmark = [pytest.mark.slow, pytest.mark.studies]


def _run(tmp_path: Path, name: str) -> dict:
    out = tmp_path / name
    assert main(["study", str(EXPERIMENTS / f"{name}.toml"), "-o", str(out), "-q"]) == 0
    return json.loads((out / "summary.json").read_text(encoding="utf-8"))


def test_axial_translation_of_a_layer_in_a_gel(tmp_path):
    variants = _run(tmp_path, "fig5b_axial_layer_gel_test")["variants"]
    v = variants["mismatched"]
    s, rows = v["summary"], v["rows"]
    assert s["wrong_tracks"] == 0 and s["min_tracking_ratio"] >= 0.95
    # The layer's 300 µm move in true depth, measured within 2 % (0.13 % measured); a gel left
    # out of the optics would give 26 % less (tests/recon/test_specimen_recon.py).
    last = rows[-1]
    assert last["u_true_z"] == pytest.approx(300.0)
    assert abs(last["u_meas_z"] - last["u_true_z"]) < 0.02 * last["u_true_z"]
    assert s["worst_u_rmsd_z"] < 2.7
    assert s["worst_u_rmsd_x"] < 0.4 and s["worst_u_rmsd_y"] < 0.55  # the air study's bounds
    # The same frames reconstructed as if the gel were air: the move comes out short by the
    # axial scale of the optics (0.736: rays of 0.2 NA from a gel of 1.35 into air).
    air = variants["as_air"]["rows"][-1]
    assert air["u_meas_z"] / air["u_true_z"] == pytest.approx(0.736, abs=0.02)


def test_simple_shear_in_a_gel(tmp_path):
    for name, v in _run(tmp_path, "fig6c_simple_shear_gel_test")["variants"].items():
        s = v["summary"]
        assert s["wrong_tracks"] == 0 and s["min_tracking_ratio"] >= 0.95, name
        assert s["worst_u_rmsd_z"] < 6.2 and s["worst_u_rmsd_x"] < 0.45, name
        # The air study's acceptance bounds: in-plane 0.4 % RMSD and 0.25 % worst mean error,
        # the components that differentiate the axial displacement 4.5 %; E_xz (the imposed
        # shear, true depth in its denominator) within 1.2 % RMSD (0.56 and 0.65 % measured).
        for i, c in enumerate(("xx", "yy", "xy", "zz", "xz", "yz")):
            cap_rmsd, cap_mean = (0.4, 0.25) if i < 3 else (4.5, 4.5)
            assert s[f"pooled_E_rmsd_{c}"] < cap_rmsd / 100, (name, c)
            assert s[f"worst_E_abs_mean_err_{c}"] < cap_mean / 100, (name, c)
        assert s["pooled_E_rmsd_xz"] < 0.012, name
