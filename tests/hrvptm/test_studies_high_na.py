"""Long tier: the paper's studies at high NA, 1 µm particles in water under a 40×/0.8 water
objective with matched f/25 lenslets (scenes/water_40x_small*.xml), end to end at test size:
translation along x, translation along z and simple shear
(scenes/experiments/water40x_*_test.toml).

The frames are ray traced through the glass microlens array and reconstructed with ideal
lenslets and the wave-optics PSF bank (``psf_model = "auto"``). The bounds are derived from
seed-2 and seed-3 copies of the three files (the seed-1 files run here are not used for them):
each quantity must stay within 2× the larger of the two seeds' values (strain at least 0.05 %,
as for the paper's studies), so that a regression in any stage fails them.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hrvptm.cli import main

EXPERIMENTS = Path(__file__).resolve().parents[2] / "scenes" / "experiments"

pytestmark = [pytest.mark.slow, pytest.mark.studies]

#: The larger of the seed-2 and seed-3 runs of each study (displacements µm, strains as
#: fractions): the pooled and worst-frame displacement RMSD per axis, the largest |mean
#: displacement error| of a frame per axis, and per strain component the pooled RMSD and the
#: worst frame's |mean error|; ``min_tracked``: the fewer particles of 20 tracked in a frame.
_CALIBRATION_TABLE = """
water40x_translation_x_test
min_tracked 20
pooled_u_rmsd_x 0.04
worst_u_rmsd_x 0.0477
max_mean_err_x 0.0137
pooled_u_rmsd_y 0.0264
worst_u_rmsd_y 0.0293
max_mean_err_y 0.0123
pooled_u_rmsd_z 0.154
worst_u_rmsd_z 0.212
max_mean_err_z 0.0605
pooled_E_rmsd_xx 0.00246
worst_E_abs_mean_err_xx 0.00145
pooled_E_rmsd_yy 0.00195
worst_E_abs_mean_err_yy 0.00119
pooled_E_rmsd_zz 0.00717
worst_E_abs_mean_err_zz 0.0117
pooled_E_rmsd_xy 0.00164
worst_E_abs_mean_err_xy 0.000762
pooled_E_rmsd_xz 0.00294
worst_E_abs_mean_err_xz 0.00427
pooled_E_rmsd_yz 0.00426
worst_E_abs_mean_err_yz 0.00487
water40x_translation_z_test
min_tracked 19
pooled_u_rmsd_x 0.0203
worst_u_rmsd_x 0.0262
max_mean_err_x 0.00704
pooled_u_rmsd_y 0.03
worst_u_rmsd_y 0.0381
max_mean_err_y 0.0054
pooled_u_rmsd_z 0.0851
worst_u_rmsd_z 0.0982
max_mean_err_z 0.066
pooled_E_rmsd_xx 0.00184
worst_E_abs_mean_err_xx 0.000714
pooled_E_rmsd_yy 0.000956
worst_E_abs_mean_err_yy 0.000774
pooled_E_rmsd_zz 0.0124
worst_E_abs_mean_err_zz 0.0207
pooled_E_rmsd_xy 0.00136
worst_E_abs_mean_err_xy 0.000778
pooled_E_rmsd_xz 0.00401
worst_E_abs_mean_err_xz 0.00391
pooled_E_rmsd_yz 0.00381
worst_E_abs_mean_err_yz 0.0033
water40x_simple_shear_test
min_tracked 16
pooled_u_rmsd_x 0.0284
worst_u_rmsd_x 0.0369
max_mean_err_x 0.00656
pooled_u_rmsd_y 0.0274
worst_u_rmsd_y 0.0339
max_mean_err_y 0.011
pooled_u_rmsd_z 0.0631
worst_u_rmsd_z 0.085
max_mean_err_z 0.0203
pooled_E_rmsd_xx 0.00117
worst_E_abs_mean_err_xx 0.00146
pooled_E_rmsd_yy 0.00137
worst_E_abs_mean_err_yy 0.00189
pooled_E_rmsd_zz 0.0122
worst_E_abs_mean_err_zz 0.0195
pooled_E_rmsd_xy 0.000781
worst_E_abs_mean_err_xy 0.00105
pooled_E_rmsd_xz 0.00472
worst_E_abs_mean_err_xz 0.00637
pooled_E_rmsd_yz 0.00377
worst_E_abs_mean_err_yz 0.0044
"""
_STRAINS = ("xx", "yy", "zz", "xy", "xz", "yz")


def _calibration() -> dict[str, dict[str, float]]:
    out: dict[str, dict[str, float]] = {}
    study = ""
    for line in _CALIBRATION_TABLE.strip().splitlines():
        key, *value = line.split()
        if not value:
            study = key
            out[study] = {}
        else:
            out[study][key] = float(value[0])
    return out


CALIBRATION = _calibration()


def _run(tmp_path: Path, name: str) -> dict:
    out = tmp_path / name
    assert main(["study", str(EXPERIMENTS / f"{name}.toml"), "-o", str(out), "-q"]) == 0
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    return summary["variants"]["mismatched"]


def _measured(v: dict) -> dict[str, float]:
    s, rows = v["summary"], v["rows"]
    m = {}
    for a in "xyz":
        m[f"pooled_u_rmsd_{a}"] = s[f"pooled_u_rmsd_{a}"]
        m[f"worst_u_rmsd_{a}"] = s[f"worst_u_rmsd_{a}"]
        m[f"max_mean_err_{a}"] = max(abs(r[f"u_meas_{a}"] - r[f"u_true_{a}"]) for r in rows)
    for c in _STRAINS:
        m[f"pooled_E_rmsd_{c}"] = s[f"pooled_E_rmsd_{c}"]
        m[f"worst_E_abs_mean_err_{c}"] = s[f"worst_E_abs_mean_err_{c}"]
    return m


def _within_calibration(v: dict, study: str) -> None:
    """No wrong track or failed frame, at most one particle fewer tracked in a frame than the
    calibration seeds' fewest, and each quantity within 2× its calibration (strains at least
    0.05 %)."""
    s = v["summary"]
    assert s["wrong_tracks"] == 0 and s["failed_frames"] == 0
    assert s["min_tracking_ratio"] >= 0.9
    cal = CALIBRATION[study]
    assert all(r["n_tracked"] >= cal["min_tracked"] - 1 for r in v["rows"])
    for key, value in _measured(v).items():  # every key of the table but min_tracked
        floor = 0.0005 if "_E_" in key else 0.0
        assert value < max(2 * cal[key], floor), (study, key, value, cal[key])


def test_high_na_translation_along_x(tmp_path):
    study = "water40x_translation_x_test"
    v = _run(tmp_path, study)
    _within_calibration(v, study)


def test_high_na_translation_along_z(tmp_path):
    study = "water40x_translation_z_test"
    v = _run(tmp_path, study)
    _within_calibration(v, study)
    last = v["rows"][-1]
    assert last["u_true_z"] == pytest.approx(4.0)
    # The 4 µm move, with the depth-dependent bias subtracted: seeds 2 and 3 measure 0.9835 and
    # 0.9927 of it; within 2× the larger shortfall. Without the subtraction it comes out
    # 0.955 (seed 1; 0.946 with the ray bank), which this bound refuses.
    ratio = last["u_meas_z"] / last["u_true_z"]
    assert abs(ratio - 1.0) < 2 * (1.0 - 0.9835), ratio


def test_high_na_simple_shear(tmp_path):
    study = "water40x_simple_shear_test"
    v = _run(tmp_path, study)
    _within_calibration(v, study)
    last = v["rows"][-1]
    assert 2 * last["E_true_xz"] == pytest.approx(0.25)
    # γ = 25 %: with the depth-dependent bias subtracted, 2 E_xz reads 0.69 and 0.18 % low at
    # seeds 2 and 3; within 2× the larger. Without the subtraction the axial scale comes out
    # 3–5 % short and 2 E_xz 2.06 and 1.43 % high at seeds 1 and 2 (0.26 % at seed 3), which
    # this bound refuses.
    assert abs(2 * (last["E_meas_xz"] - last["E_true_xz"])) < 2 * 0.0069
