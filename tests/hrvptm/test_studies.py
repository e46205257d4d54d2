"""Regression tests: every paper study at test size, end to end (render → reconstruct → track →
compare with the truth), through the ``hrvptm`` command line.

Scale: 600 × 450 px sensor (40 × 30 lenslets of the paper's optics, scenes/medium*.xml),
15–24 particles, 5·10⁴ rays per particle, 4–13 frames; the physics is the paper's (glass
lenslets in the images, ideal lenslets in the reconstruction, SNR 17, 5 µm voxels, 3 RL
iterations). Bounds are about 1.5–2× the values measured when the tests were written (see
docs/validation.md) and never looser than the paper's figures where the paper gives one, so
that a regression in any stage (a biased projector, a lost deconvolution, a linker that drops
or swaps particles, a wrong strain definition) fails them.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hrvptm.cli import main

EXPERIMENTS = Path(__file__).resolve().parents[2] / "scenes" / "experiments"
_RUNS: dict[str, dict] = {}

pytestmark = [pytest.mark.slow, pytest.mark.studies]


@pytest.fixture(scope="module")
def reports(tmp_path_factory):
    root = tmp_path_factory.mktemp("studies")

    def run(name: str) -> dict:
        if name not in _RUNS:
            out = root / name
            assert main(["study", str(EXPERIMENTS / f"{name}.toml"), "-o", str(out), "-q"]) == 0
            summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
            _RUNS[name] = {"out": out, "summary": summary}
        return _RUNS[name]

    return run


def _v(run: dict, variant: str = "mismatched") -> dict:
    return run["summary"]["variants"][variant]


def _series_ok(v: dict, min_ratio: float = 0.95) -> None:
    s = v["summary"]
    assert s["wrong_tracks"] == 0
    assert s["min_tracking_ratio"] >= min_ratio
    assert all(r["n_tracked"] >= 10 for r in v["rows"])


#: Strain errors measured at test size (%, fields smoothed by GCV; both variants of 6c, the
#: larger): the pooled RMSD, then the worst frame's |mean error|, of xx, yy, xy, zz, xz, yz.
#: 6b: the larger of two runs whose detectors find different particles (worst-frame mean E_yy
#: 0.018 and 0.103 %, E_zz 0.60 and 2.05 %, each from one frame of 16–24 tracked particles).
_MEASURED_E_TABLE = """
fig6a_uniaxial_test      0.143 0.140 0.070 1.988 1.376 0.983  0.076 0.034 0.038 2.147 0.571 0.501
fig6b_rotation_test      0.125 0.115 0.110 2.217 1.145 1.289  0.101 0.103 0.064 2.053 0.421 0.804
fig6c_simple_shear_test  0.083 0.035 0.096 1.439 0.408 0.690  0.022 0.048 0.057 1.555 0.135 0.279
fig7_shear_impact_test   0.186 0.033 0.109 0.581 0.382 0.269  0.053 0.034 0.033 0.613 0.239 0.095
demo_simple_shear        0.123 0.143 0.103 2.662 0.471 0.616  0.049 0.048 0.061 2.588 0.313 0.418
"""
#: study: ((pooled RMSD of the six components), (worst |mean error| of the six components)), %
MEASURED_E = {
    study: (tuple(map(float, values[:6])), tuple(map(float, values[6:])))
    for study, *values in map(str.split, _MEASURED_E_TABLE.strip().splitlines())
}


def _strain_ok(v: dict, study: str) -> None:
    """Strain against the imposed one, each component within 2× the error measured for this
    study (at least 0.05 %, the scatter of one particle's localisation), and never above the
    acceptance bounds: in-plane (xx, yy, xy) 0.4 % RMSD and 0.25 % mean error (the paper:
    < 1 % and < 3 %); the components that differentiate the axial displacement (zz, xz, yz;
    the paper excludes zz and zy) rest on 15–24 particles with ≈ 2–3 µm axial noise: 4.5 %."""
    s = v["summary"]
    rmsd, mean = MEASURED_E[study]
    for i, c in enumerate(("xx", "yy", "xy", "zz", "xz", "yz")):
        cap_rmsd, cap_mean = (0.4, 0.25) if i < 3 else (4.5, 4.5)
        bound_rmsd = min(max(2 * rmsd[i], 0.05), cap_rmsd) / 100
        bound_mean = min(max(2 * mean[i], 0.05), cap_mean) / 100
        assert s[f"pooled_E_rmsd_{c}"] < bound_rmsd, (c, s[f"pooled_E_rmsd_{c}"])
        assert s[f"worst_E_abs_mean_err_{c}"] < bound_mean, (c, s[f"worst_E_abs_mean_err_{c}"])


def test_fig4a_localization_against_snr(reports):
    rows = _v(reports("fig4a_localization_snr_test"))["rows"]
    assert [r["snr"] for r in rows] == [90, 50, 17, 5]
    for r in rows[:3]:  # SNR 90 … 17
        assert r["recall"] >= 0.8 and r["precision"] >= 0.95
        assert r["rmsd_x"] < 0.3 and r["rmsd_y"] < 0.3 and r["rmsd_z"] < 6.0
    low = rows[3]  # SNR 5: fewer particles, larger errors, still localised
    assert 0.6 <= low["recall"] and low["rmsd_x"] < 0.7 and low["rmsd_z"] < 9.0
    assert low["rmsd_x"] > rows[0]["rmsd_x"]  # the noise dependence is there


def test_fig4b_zero_displacement_pairs(reports):
    run = reports("fig4b_zero_displacement_test")
    v = _v(run)
    assert v["summary"]["wrong_links"] == 0
    rows = v["rows"]
    assert [r["snr"] for r in rows] == [90, 17, 5]
    for r in rows:
        assert r["tracking_ratio"] >= 0.9
        assert abs(r["u_mean_x"]) < 0.2 and abs(r["u_mean_y"]) < 0.2  # no spurious motion
    for r in rows[:2]:
        assert r["u_rmsd_x"] < 0.4 and r["u_rmsd_y"] < 0.4 and r["u_rmsd_z"] < 2.5
    assert rows[2]["u_rmsd_x"] < 0.7 and rows[2]["u_rmsd_z"] < 6.0
    assert (run["out"] / "plots" / "pairs.png").is_file()


def test_fig4c_noise_floor_against_frame_rate(reports):
    rows = _v(reports("fig4c_frame_rate_test"))["rows"]
    assert [r["fps"] for r in rows] == [100, 4000, 25000]
    snr = [r["snr"] for r in rows]
    assert snr[0] > 40 and snr[0] > snr[1] > snr[2]  # the camera model: light starved at speed
    slow, fast = rows[0], rows[2]
    for r in rows:
        assert r["tracking_ratio"] >= 0.9
    assert slow["u_rmsd_x"] < 0.15 and slow["u_rmsd_z"] < 1.0
    assert rows[1]["u_rmsd_x"] < 0.3 and rows[1]["u_rmsd_z"] < 2.0  # 4000 fps: still low
    # At 25 000 fps (SNR ≈ 3.6) the light-starved frames raise the noise floor (measured ×8).
    assert fast["u_rmsd_x"] > 3 * slow["u_rmsd_x"] and fast["u_rmsd_z"] > 3 * slow["u_rmsd_z"]
    assert fast["u_rmsd_x"] < 0.8 and fast["u_rmsd_z"] < 6.0
    # recon measures each frame's SNR as the simulator defines it (camera gain given) ...
    for r in rows:
        assert r["snr_measured"] == pytest.approx(r["snr"], rel=0.1), r
    # ... and the σ follows it: the light-starved pair's σ is several times the bright one's,
    # as its error is (sigma_snr_um)
    for ax in "xyz":
        assert fast[f"u_sigma_rms_{ax}"] > 2.5 * slow[f"u_sigma_rms_{ax}"], ax
    # measured x 69 / 93, y 60 / 83, z 54 / 94 % within 1σ / 2σ (without the SNR term
    # 67 / 85, 49 / 78, 60 / 89 %)
    s = _v(reports("fig4c_frame_rate_test"))["summary"]
    for ax in "xyz":
        assert s[f"u_coverage_2sigma_{ax}"] >= 0.8, (ax, s[f"u_coverage_2sigma_{ax}"])


@pytest.mark.parametrize("axis", ["x", "y"])
def test_fig5a_inplane_translation(reports, axis):
    run = reports(f"fig5a_translation_{axis}_test")
    v = _v(run)
    _series_ok(v)
    s = v["summary"]
    # Paper: RMSD 0.60 (x), 0.59 (y), 3.2 µm (z); the acceptance bounds.
    assert s["pooled_u_rmsd_x"] < 0.45 and s["pooled_u_rmsd_y"] < 0.45
    assert s["pooled_u_rmsd_z"] < 3.2
    # mean measured displacement of each frame against the imposed one: measured at most
    # 0.04 (x), 0.09 (y) in-plane and 1.13 µm axially
    for r in v["rows"]:
        assert abs(r["u_meas_x"] - r["u_true_x"]) < 0.2 and abs(r["u_meas_y"] - r["u_true_y"]) < 0.2
        assert abs(r["u_meas_z"] - r["u_true_z"]) < 2.3


def test_uncertainty_coverage_pooled_over_the_studies(reports):
    """The σ of positions (4a) and of displacements (4b, 5a x and y) hold
    68 ± 5 % and 95 ± 3 % of the errors per axis, pooled. Calibrated on seed-2, -3 and -4
    runs of these and 4c (benchmarks/calibrate_sigma.py --snr-term, 1226 errors), measured on
    these seed-1 frames: x 71 / 93 %, y 67 / 94 %, z 69 / 97 % (358 errors per axis; per
    study 44–90 % within 1σ). With 4c's 72 errors pooled too (its own coverage is checked by
    test_fig4c_noise_floor_against_frame_rate): x 70.5 / 93.3, y 66.0 / 92.1 (under the
    band's 92.5), z 66.7 / 96.7 %."""
    pooled = {}
    for name, prefix in (
        ("fig4a_localization_snr_test", ""),
        ("fig4b_zero_displacement_test", "u_"),
        ("fig5a_translation_x_test", "u_"),
        ("fig5a_translation_y_test", "u_"),
    ):
        s = _v(reports(name))["summary"]
        n = s[f"{prefix}coverage_n"]
        assert n >= 60, name
        for ax in "xyz":
            for k in (1, 2):
                key = f"{prefix}coverage_{k}sigma_{ax}"
                pooled.setdefault((k, ax), []).append((n, s[key]))
    for (k, ax), vals in pooled.items():
        frac = sum(n * c for n, c in vals) / sum(n for n, _ in vals)
        target, tol = (0.6827, 0.05) if k == 1 else (0.9545, 0.03)
        assert abs(frac - target) <= tol, (ax, k, frac)


def test_fig5b_axial_translation_of_a_layer(reports):
    v = _v(reports("fig5b_axial_layer_test"))
    _series_ok(v, min_ratio=0.8)
    s = v["summary"]
    # with the simulator self-calibration of the depth-dependent bias ([track.axial]): measured
    # 1.72 / 0.165 / 0.274 µm (without it 5.3 / 0.27 / 0.37; paper: worst 39.1 / 5.4 / 8.7 µm)
    assert s["worst_u_rmsd_z"] < 3.5
    assert s["worst_u_rmsd_x"] < 0.4 and s["worst_u_rmsd_y"] < 0.55
    last = v["rows"][-1]  # the layer's mean move, 300 µm: measured within 0.1 µm
    assert last["u_meas_z"] == pytest.approx(last["u_true_z"], abs=2.0)
    # one layer of particles: no 3-D strain is compared or plotted
    assert all(r["E_rmsd_xx"] is None or r["E_rmsd_xx"] != r["E_rmsd_xx"] for r in v["rows"])
    run = reports("fig5b_axial_layer_test")
    assert sorted(p.name for p in (run["out"] / "plots").iterdir()) == [
        "displacement.png",
        "uncertainty.png",  # |error| against σ
        "vectors.png",
    ]


def test_fig6a_uniaxial_tension(reports):
    v = _v(reports("fig6a_uniaxial_test"))
    _series_ok(v)
    _strain_ok(v, "fig6a_uniaxial_test")
    last = v["rows"][-1]  # stretch 25 %: E_xx = 0.281 (measured 0.2818)
    assert last["E_meas_xx"] == pytest.approx(last["E_true_xx"], abs=0.001)


def test_fig6b_rigid_rotation(reports):
    v = _v(reports("fig6b_rotation_test"))
    _series_ok(v)
    _strain_ok(v, "fig6b_rotation_test")
    # displacements up to the rotation's 45°: worst frame RMSD measured 0.44 / 0.89 / 3.98 µm
    s = v["summary"]
    assert s["worst_u_rmsd_x"] < 0.9 and s["worst_u_rmsd_y"] < 1.8 and s["worst_u_rmsd_z"] < 8.0


def test_fig6c_simple_shear_with_and_without_inverse_crime(reports):
    run = reports("fig6c_simple_shear_test")
    mis, mat = _v(run, "mismatched"), _v(run, "matched")
    for v in (mis, mat):
        _series_ok(v)
        _strain_ok(v, "fig6c_simple_shear_test")
        # γ = 25 %: 2 E_xz measured 24.66 % and 24.56 %, the detector finding the two
        # particles 5 µm under the top of the seeded box (without them 24.85 / 24.83 %; the
        # exact-gradient fields change nothing). Their z displacement errors (−3.6,
        # −2.2 µm) pull ∂u_z/∂x at the hull's edge. The scatter of this number from the
        # localisation errors alone (these particles, the measured error RMS 0.18 / 0.17 /
        # 1.8 µm, 200 draws, gridded as here) is 0.17 % (mean 25.00 %), and seed 2 measures
        # 24.95 %: scatter, not a bias. The bound is 3.5 σ of that scatter
        last = v["rows"][-1]
        assert 2 * last["E_meas_xz"] == pytest.approx(2 * last["E_true_xz"], abs=0.006)
    # The glass lenslets barely change the result (the gap the report shows): measured 0.003 µm
    gap = abs(mis["summary"]["pooled_u_rmsd_x"] - mat["summary"]["pooled_u_rmsd_x"])
    assert gap < 0.01
    for name in ("displacement.png", "strain.png", "vectors.png"):
        assert (run["out"] / "plots" / name).is_file()
    # the report's table shows the measured values of both variants
    md = (run["out"] / "summary.md").read_text(encoding="utf-8")
    row = next(line for line in md.splitlines() if line.startswith("| strain RMSD E_xz |"))
    for v in (mis, mat):
        assert f"{100 * v['summary']['pooled_E_rmsd_xz']:.2f} % ✓" in row, row


def test_fig7_shear_impact_history(reports):
    run = reports("fig7_shear_impact_test")
    v = _v(run)
    _series_ok(v)
    _strain_ok(v, "fig7_shear_impact_test")
    for r in v["rows"]:
        # the shear history: 2 E_xz within 0.48 % of the imposed γ (measured, worst frame)
        assert 2 * r["E_meas_xz"] == pytest.approx(2 * r["E_true_xz"], abs=0.01)
        # E_zz follows the finite-deformation theory γ²/2 of the *measured* shear (the paper's
        # Fig. 7 check): measured within 0.62 % (at the peak, γ = 31 %)
        assert abs(r["E_meas_zz"] - (2 * r["E_meas_xz"]) ** 2 / 2) < 0.012
    for name in ("strain_history.png", "slices.png"):
        assert (run["out"] / "plots" / name).is_file()


#: The stiff-inclusion study at test size, measured (pooled over frames 1–4, at the supported
#: nodes, %): the strain RMSD against the imposed field, then against the *ideal* field (the
#: imposed field at the detected particles, gridded the study's way: the sampling floor), of
#: xx, yy, zz, xy, xz, yz. 30 particles cannot resolve a 130 µm sphere: the in-plane error is
#: the floor (ratio 0.98–1.01); the components that differentiate u_z add the axial noise.
_INCLUSION_E_RMSD = (5.03, 1.97, 2.45, 0.99, 1.40, 1.27)
_INCLUSION_E_IDEAL = (5.03, 1.95, 1.65, 1.01, 0.90, 0.79)


def test_stiff_inclusion_against_the_truth_and_the_sampling_floor(reports):
    """A heterogeneous field end to end (a nearly rigid sphere in a matrix stretched along x
    to 20 %): every frame detected and tracked, the per-particle displacement errors of the
    homogeneous studies, and the strain at the nodes against the analytic field: within 2×
    the measured error, and in-plane on the sampling floor (measured / ideal < 1.25), so that
    smoothing that flattens the gradients or a tracker that loses accuracy fails."""
    run = reports("inclusion_stretch_test")
    v = _v(run)
    _series_ok(v)
    s = v["summary"]
    assert s["failed_frames"] == 0
    assert all(r["n_detected"] >= 27 for r in v["rows"])  # of 30 (measured 28–30)
    # per particle, measured 0.23 / 0.21 / 3.25 µm
    assert s["pooled_u_rmsd_x"] < 0.45 and s["pooled_u_rmsd_y"] < 0.45
    assert s["pooled_u_rmsd_z"] < 6.5
    # the gridded displacement at the nodes, measured 2.6 / 1.3 / 2.6 µm (ideal 2.6 / 1.3 / 1.0)
    assert s["pooled_u_node_rmsd_x"] < 5.2 and s["pooled_u_node_rmsd_y"] < 2.7
    assert s["pooled_u_node_rmsd_z"] < 5.3
    for i, c in enumerate(("xx", "yy", "zz", "xy", "xz", "yz")):
        assert s[f"pooled_E_rmsd_{c}"] < 2 * _INCLUSION_E_RMSD[i] / 100, c
        # the floor itself: a regression in the truth or the gridding moves it
        ideal = s[f"pooled_E_ideal_rmsd_{c}"]
        assert 0.5 * _INCLUSION_E_IDEAL[i] / 100 < ideal < 2 * _INCLUSION_E_IDEAL[i] / 100, c
        assert s[f"pooled_E_ratio_ideal_{c}"] < (1.25 if c in ("xx", "yy", "xy") else 3.2), c
    # the mean strain of each frame: worst measured 0.29 / 0.05 / 0.02 / 1.34 % (xx, yy, xy,
    # zz); 2× that, at least 0.05 % (as for the homogeneous studies)
    for c, bound in (("xx", 0.0058), ("yy", 0.001), ("xy", 0.0005), ("zz", 0.0268)):
        assert s[f"worst_E_abs_mean_err_{c}"] < bound, c
    md = (run["out"] / "summary.md").read_text(encoding="utf-8")
    assert "## Heterogeneous field against the truth and the sampling floor" in md


def test_rerun_resumes_without_rendering_or_reconstructing_again(reports):
    run = reports("fig6b_rotation_test")
    out = run["out"]
    frames = sorted((out / "mismatched" / "dataset" / "frames").glob("*.tif"))
    vols = sorted((out / "mismatched" / "volumes").glob("[0-9]*.tif"))
    before = {p: p.stat().st_mtime_ns for p in frames + vols}

    def forbidden(*args, **kwargs):
        raise AssertionError("a finished frame was rendered or reconstructed again")

    import lfsim.render
    import recon.pipeline

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(lfsim.render, "render_particles", forbidden)
        mp.setattr(lfsim.render, "render_white", forbidden)
        mp.setattr(recon.pipeline, "richardson_lucy", forbidden)
        args = ["study", str(EXPERIMENTS / "fig6b_rotation_test.toml"), "-o", str(out), "-q"]
        assert main(args) == 0
    assert {p: p.stat().st_mtime_ns for p in before} == before
    state = json.loads((out / "study.json").read_text(encoding="utf-8"))
    assert len(state["runs"]) == 2


def test_demo_prints_the_summary_table(tmp_path, capsys):
    assert main(["demo", "-o", str(tmp_path / "demo")]) == 0
    text = capsys.readouterr().out
    assert "γ imposed" in text and "report:" in text
    summary = json.loads((tmp_path / "demo" / "summary.json").read_text(encoding="utf-8"))
    v = summary["variants"]["mismatched"]
    _series_ok(v)
    _strain_ok(v, "demo_simple_shear")


def test_collect_gathers_reports_with_their_plots(reports, tmp_path):
    six_b, four_a = reports("fig6b_rotation_test"), reports("fig4a_localization_snr_test")
    page = tmp_path / "docs" / "validation.md"
    plots = page.parent / "validation"

    def collect(*runs, overwrite=False):
        argv = ["collect", *[str(r["out"]) for r in runs], "-o", str(page), "-q"]
        return main([*argv, "--overwrite"] if overwrite else argv)

    assert collect(four_a) == 0  # a first collection writes the page and its plots
    assert collect(six_b, four_a) == 2  # the page exists: replaced only with --overwrite
    notes = plots / "notes.txt"  # the user's own files beside the plots are never touched
    notes.write_text("kept", encoding="utf-8")
    mine = plots / "fig4a_localization_snr_test" / "mine.png"
    mine.write_bytes(b"png")
    assert collect(six_b, four_a, overwrite=True) == 0
    text = page.read_text(encoding="utf-8")
    assert "## Study `fig6b_rotation_test`" in text
    assert "(validation/fig6b_rotation_test/strain.png)" in text
    assert (plots / "fig6b_rotation_test" / "strain.png").is_file()
    # A collection that no longer shows 4a removes the plots collect wrote for it, not the
    # user's.
    written = sorted((plots / "fig4a_localization_snr_test").glob("*.png"))
    assert collect(six_b, overwrite=True) == 0
    assert not any(p.exists() for p in written if p != mine)
    assert mine.read_bytes() == b"png" and notes.read_text(encoding="utf-8") == "kept"
