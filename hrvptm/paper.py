"""The paper's numbers (§4–5) and the studies' acceptance bounds, per figure.

Each :class:`Reference` names a key of a variant's pooled summary (:mod:`hrvptm.analysis`),
the paper's value and, where the paper states a bound, the test ``ours <= bound``. Values in
the units of the summary (µm, strain as a fraction).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Reference:
    """One number the report puts side by side with the paper's.

    Attributes
    ----------
    label : str
    key : str
        Key of the variant summary.
    paper : float or None
        The paper's value (None: the paper gives a trend, not a number: ``note``).
    bound : float or None
        Acceptance bound (ours must not exceed it); None: reported only.
    unit : {"um", "strain"}
    note : str
    """

    label: str
    key: str
    paper: float | None = None
    bound: float | None = None
    unit: str = "um"
    note: str = ""


_DISP = {"x": 0.60, "y": 0.59, "z": 3.2}
_STRAIN_OK = ("xx", "yy", "xy", "xz")  # components not dominated by z (paper §4.3)
_ALL = ("xx", "yy", "zz", "xy", "xz", "yz")


def _strain_refs() -> list[Reference]:
    refs = [
        Reference(f"strain RMSD E_{c}", f"pooled_E_rmsd_{c}", 0.01, 0.01, "strain", "paper: < 1 %")
        for c in _STRAIN_OK
    ]
    refs += [
        Reference(f"strain RMSD E_{c}", f"pooled_E_rmsd_{c}", None, None, "strain", "z-dominated")
        for c in ("zz", "yz")
    ]
    refs += [
        Reference(
            f"worst frame abs. mean error E_{c}",
            f"worst_E_abs_mean_err_{c}",
            0.03,
            0.03,
            "strain",
            "paper: total mean error < 3 %",
        )
        for c in _ALL
    ]
    return refs


def _worst_pairs(note: str) -> list[Reference]:
    """The worst zero-displacement pair's RMSD per axis: the paper shows a trend (``note``)."""
    return [
        Reference(f"displacement RMSD {c}, worst pair", f"worst_u_rmsd_{c}", None, None, "um", note)
        for c in "xyz"
    ]


REFERENCES: dict[str, list[Reference]] = {
    "4a": [
        Reference("localization RMSD x (pooled)", "pooled_rmsd_x", 5.2),
        Reference("localization RMSD y (pooled)", "pooled_rmsd_y", 3.2),
        Reference("localization RMSD z (pooled)", "pooled_rmsd_z", 9.5),
        Reference("abs. mean error x, worst SNR", "worst_abs_mean_x", 0.35),
        Reference("abs. mean error y, worst SNR", "worst_abs_mean_y", 0.34),
        Reference("abs. mean error z, worst SNR", "worst_abs_mean_z", 3.5),
    ],
    "4b": _worst_pairs("paper: flat over SNR 90 → 5"),
    "4c": _worst_pairs("paper: constant up to ≈ 4000 fps, then rising"),
    "5a": [
        Reference(
            f"displacement RMSD {c} (pooled)", f"pooled_u_rmsd_{c}", v, v if c == "z" else 0.6
        )
        for c, v in _DISP.items()
    ]
    + [  # the paper's figure is the largest RMSD over the displacements it tested
        Reference(
            f"displacement RMSD {c}, worst frame",
            f"worst_u_rmsd_{c}",
            v,
            v / 2 if c == "z" else v,
            note="bound: half the paper's" if c == "z" else "",
        )
        for c, v in _DISP.items()
    ],
    "5b": [
        Reference("displacement RMSD z, worst step", "worst_u_rmsd_z", 39.1),
        Reference("displacement RMSD x, worst step", "worst_u_rmsd_x", 5.4),
        Reference("displacement RMSD y, worst step", "worst_u_rmsd_y", 8.7),
    ],
    "6a": _strain_refs(),
    "6b": _strain_refs(),
    "6c": _strain_refs(),
    "7": [
        Reference(
            "worst frame abs. mean error E_xz", "worst_E_abs_mean_err_xz", None, None, "strain"
        ),
        Reference(
            "worst frame abs. mean error E_zz (vs γ²/2)",
            "worst_E_abs_mean_err_zz",
            None,
            None,
            "strain",
            "paper: E_zz follows finite-deformation theory",
        ),
    ],
}


def references(figure: str) -> list[Reference]:
    """The references of a figure (empty for an unknown or empty figure)."""
    return list(REFERENCES.get(figure, []))
