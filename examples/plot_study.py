"""
A paper study at test size
==========================

:func:`hrvptm.run_study` runs one of the paper's studies end to end — simulate,
reconstruct, track, compare with the truth — into a report folder (``summary.md``,
``summary.json``, tables and plots). Here the rigid translation along x of Fig. 5a at test
size (24 particles, five frames, the paper's optics on a 600 × 450 px sensor).

Every study of the paper has a test-size file in ``scenes/experiments/`` (``*_test.toml``);
from a shell, any of them runs as::

    .venv/bin/hrvptm study scenes/experiments/fig6a_uniaxial_test.toml -o out/fig6a_test

and the full-size ones without ``_test``. The long tier of the tests
(``.venv/bin/python -m pytest -q -m studies``) runs all of them; ``hrvptm collect`` gathers
their reports into one page (the validation pages of this site).
"""

# %%
# Run the study
# -------------
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
from matplotlib.image import imread

import hrvptm

ROOT = Path(hrvptm.__file__).resolve().parents[1]
study = hrvptm.load_study(ROOT / "scenes" / "experiments" / "fig5a_translation_x_test.toml")
report = Path(tempfile.mkdtemp()) / "fig5a_test"
summary = hrvptm.run_study(study, report, progress=False)
print(summary["status"], "— variants:", ", ".join(summary["variants"]))

# %%
# Side by side with the paper
# ---------------------------
# Each row: a quantity, the paper's value, this run's, and whether it meets the bound.
for row in summary["comparison"]:
    for variant in summary["variants"]:
        ok = "meets" if row[f"{variant}_meets"] else "beyond"
        print(
            f"{row['label']:<36} paper {row['paper']:>6} {row['unit']}  "
            f"{variant} {row[variant]:.3g} ({ok} the bound {row['bound']})"
        )

# %%
# The report's displacement plot
# ------------------------------
fig, ax = plt.subplots(figsize=(8, 5))
ax.imshow(imread(report / "plots" / "displacement.png"))
ax.set_axis_off()
fig.tight_layout()
