"""Figures of a study report, in the spirit of the paper's Figs. 4–7 (matplotlib, Agg).

Every function takes ``{variant: Analysis}`` (:mod:`hrvptm.analysis`) and writes one PNG
atomically; it returns the path. Variants are drawn in the same panels (solid: the
no-inverse-crime run, dashed: the matched model, dotted: the frames reconstructed as if the
specimen were air) so the gap between them is visible.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .compare import AXES, TENSOR_COMPONENTS

#: SNR of the paper's validations and experiments (dashed line of Figs. 4b–c).
PAPER_SNR = 17.0
STYLE = {"mismatched": "-", "matched": "--", "as_air": ":"}
LABEL = {
    "mismatched": "glass MLA → ideal model",
    "matched": "matched model",
    "as_air": "specimen left out (as air)",
}
COLORS = {"x": "tab:blue", "y": "tab:orange", "z": "tab:green"}


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> Path:
    from hrvbase.io import atomic_path

    try:
        with atomic_path(path, overwrite=True) as tmp:
            fig.savefig(tmp, format="png", dpi=110, bbox_inches="tight")
    finally:
        _plt().close(fig)
    return Path(path)


def _col(rows, key) -> np.ndarray:
    return np.array([r.get(key, math.nan) for r in rows], dtype=float)


def _band(ax, x, mean, rmsd, color, ls, label):
    ax.plot(x, mean, ls, color=color, marker="o", ms=3, label=label)
    if ls == "-":
        ax.fill_between(x, mean - rmsd, mean + rmsd, color=color, alpha=0.2, lw=0)
    else:
        ax.plot(x, mean - rmsd, ":", color=color, lw=0.8)
        ax.plot(x, mean + rmsd, ":", color=color, lw=0.8)


def plot_localization(results: dict, path: Path, title: str = "") -> Path:
    """Fig. 4a: localization RMSD and largest absolute error per axis against SNR."""
    plt = _plt()
    fig, axs = plt.subplots(1, 3, figsize=(12, 3.6), sharex=True)
    for variant, a in results.items():
        snr = _col(a.rows, "snr")
        for ax, c in zip(axs, AXES, strict=True):
            ls = STYLE.get(variant, "-")
            for key, color, marker, what in (
                ("rmsd", "k", "o", "RMSD"),
                ("maxabs", "tab:red", "s", "max |error|"),
                ("mean", "tab:blue", "^", "mean error"),
            ):
                ax.plot(
                    snr,
                    _col(a.rows, f"{key}_{c}"),
                    ls,
                    color=color,
                    marker=marker,
                    ms=3,
                    label=f"{what}, {LABEL.get(variant, variant)}",
                )
    for ax, c in zip(axs, AXES, strict=True):
        ax.axvline(PAPER_SNR, color="grey", ls="--", lw=0.8)
        ax.axhline(0, color="grey", lw=0.5)
        ax.set_xlabel("SNR")
        ax.set_ylabel(f"{c} error (µm)")
        ax.set_xscale("log")
    axs[0].legend(fontsize=6)
    fig.suptitle(title or "Localization error against SNR")
    return _save(fig, path)


def plot_uncertainty(results: dict, path: Path, title: str = "") -> Path:
    """Reported uncertainty next to the actual error, per axis.

    Top: ``|error|`` against the reported σ with the lines ``|error| = σ`` and
    ``2σ``: a right σ leaves 68 % and 95 % of the points below them. Bottom: histogram of
    ``error/σ`` against the standard normal density. Needs
    ``Analysis.arrays["uncertainty"]`` (:mod:`hrvptm.analysis`); variants without σ are
    drawn as a note.
    """
    plt = _plt()
    fig, axs = plt.subplots(2, 3, figsize=(12, 6.5))
    colors = {"mismatched": "tab:blue", "matched": "tab:orange", "as_air": "tab:red"}
    zz = np.linspace(-4, 4, 200)
    for variant, a in results.items():
        unc = a.arrays.get("uncertainty") or {}
        e = np.asarray(unc.get("error", np.zeros((0, 3))), float).reshape(-1, 3)
        sg = np.asarray(unc.get("sigma", np.zeros((0, 3))), float).reshape(-1, 3)
        ok = np.all(np.isfinite(sg) & (sg > 0), axis=1) & np.all(np.isfinite(e), axis=1)
        e, sg = e[ok], sg[ok]
        color = colors.get(variant, "k")
        label = LABEL.get(variant, variant)
        for j in range(3):
            top, bottom = axs[0, j], axs[1, j]
            if not len(e):
                top.text(0.5, 0.5, f"{label}: no σ", ha="center", transform=top.transAxes)
                continue
            z = e[:, j] / sg[:, j]
            cov1, cov2 = np.mean(np.abs(z) <= 1), np.mean(np.abs(z) <= 2)
            top.plot(
                sg[:, j],
                np.abs(e[:, j]),
                ".",
                color=color,
                ms=3,
                alpha=0.6,
                label=f"{label}: {100 * cov1:.0f} % ≤ 1σ, {100 * cov2:.0f} % ≤ 2σ",
            )
            bins = np.linspace(-4, 4, 33)
            bottom.hist(np.clip(z, -4, 4), bins=bins, density=True, histtype="step",
                        color=color, label=label)  # fmt: skip
    for j, c in enumerate(AXES):
        top, bottom = axs[0, j], axs[1, j]
        hi = top.get_xlim()[1] if top.has_data() else 1.0
        xs = np.array([0.0, hi])
        top.plot(xs, xs, "k-", lw=0.8, label="|error| = σ")
        top.plot(xs, 2 * xs, "k--", lw=0.8, label="|error| = 2σ")
        top.set_xlim(0, hi)
        top.set_ylim(bottom=0)
        top.set_xlabel(f"reported σ_{c} (µm)")
        top.set_ylabel(f"|{c} error| (µm)")
        top.legend(fontsize=6)
        bottom.plot(zz, np.exp(-0.5 * zz**2) / math.sqrt(2 * math.pi), "k-", lw=0.8,
                    label="N(0, 1)")  # fmt: skip
        bottom.set_xlabel(f"{c} error / σ (clipped at ±4)")
        bottom.set_ylabel("density")
        bottom.legend(fontsize=6)
    fig.suptitle(title or "Reported uncertainty against the actual error")
    fig.tight_layout()
    return _save(fig, path)


def plot_pairs(results: dict, path: Path, title: str = "") -> Path:
    """Figs. 4b–c: zero-displacement error (mean ± RMSD) per axis against SNR or frame rate."""
    plt = _plt()
    fig, axs = plt.subplots(1, 2, figsize=(11, 3.8))
    for variant, a in results.items():
        fps = _col(a.rows, "fps")
        use_fps = np.all(np.isfinite(fps)) and len(np.unique(fps)) > 1
        x = fps if use_fps else _col(a.rows, "snr")
        ls = STYLE.get(variant, "-")
        for c in AXES:
            _band(
                axs[0],
                x,
                _col(a.rows, f"u_mean_{c}"),
                _col(a.rows, f"u_rmsd_{c}"),
                COLORS[c],
                ls,
                f"{c}, {LABEL.get(variant, variant)}",
            )
        axs[1].plot(
            x,
            _col(a.rows, "tracking_ratio"),
            ls,
            marker="o",
            ms=3,
            label=LABEL.get(variant, variant),
        )
        for ax in axs:
            ax.set_xscale("log")
            ax.set_xlabel("camera frame rate (fps)" if use_fps else "SNR")
            if not use_fps:
                ax.axvline(PAPER_SNR, color="grey", ls="--", lw=0.8)
        if use_fps:  # Fig. 4c's right axis: the image SNR the camera model gives per frame rate
            twin = axs[1].twinx()
            twin.plot(x, _col(a.rows, "snr"), ls, color="tab:gray", marker="s", ms=3)
            twin.set_ylabel("image SNR (camera model)", color="tab:gray")
            twin.set_yscale("log")
    axs[0].axhline(0, color="grey", lw=0.5)
    axs[0].set_ylabel("displacement error (µm): mean ± RMSD")
    axs[1].set_ylabel("tracking ratio")
    axs[1].set_ylim(0, 1.05)
    axs[0].legend(fontsize=6)
    axs[1].legend(fontsize=7)
    fig.suptitle(title or "Zero-displacement pairs")
    return _save(fig, path)


def plot_displacement(results: dict, path: Path, title: str = "") -> Path:
    """Fig. 5: measured mean displacement ± RMSD against the imposed one, per axis."""
    plt = _plt()
    fig, axs = plt.subplots(1, 3, figsize=(12, 3.6))
    label = next(iter(results.values())).arrays.get("amplitude_label", "frame")
    for variant, a in results.items():
        x = _col(a.rows, "amplitude")
        ls = STYLE.get(variant, "-")
        for ax, c in zip(axs, AXES, strict=True):
            true = _col(a.rows, f"u_true_{c}")
            meas = true + _col(a.rows, f"u_mean_{c}")
            _band(
                ax,
                x,
                meas,
                _col(a.rows, f"u_rmsd_{c}"),
                COLORS[c],
                ls,
                f"measured, {LABEL.get(variant, variant)}",
            )
            ax.plot(
                x, true, "k:", lw=1, label="imposed" if variant == next(iter(results)) else None
            )
    for ax, c in zip(axs, AXES, strict=True):
        ax.set_xlabel(label)
        ax.set_ylabel(f"u_{c} (µm)")
    axs[0].legend(fontsize=6)
    fig.suptitle(title or "Displacement: measured mean ± RMSD against imposed")
    return _save(fig, path)


def plot_strain(results: dict, path: Path, title: str = "") -> Path:
    """Fig. 6 (centre): Green–Lagrange strain components, measured mean ± RMSD against the
    imposed, in % strain."""
    plt = _plt()
    fig, axs = plt.subplots(2, 3, figsize=(12, 6.5), sharex=True)
    label = next(iter(results.values())).arrays.get("amplitude_label", "frame")
    for variant, a in results.items():
        x = _col(a.rows, "amplitude")
        ls = STYLE.get(variant, "-")
        for ax, c in zip(axs.ravel(), TENSOR_COMPONENTS, strict=True):
            true = 100 * _col(a.rows, f"E_true_{c}")
            meas = 100 * _col(a.rows, f"E_meas_{c}")
            _band(
                ax,
                x,
                meas,
                100 * _col(a.rows, f"E_rmsd_{c}"),
                "tab:purple",
                ls,
                f"measured, {LABEL.get(variant, variant)}",
            )
            ax.plot(x, true, "k:", lw=1)
            ax.set_title(f"E_{c}", fontsize=9)
    for ax in axs[1]:
        ax.set_xlabel(label)
    for ax in axs[:, 0]:
        ax.set_ylabel("strain (%)")
    axs[0, 0].legend(fontsize=6)
    fig.suptitle(title or "Strain: measured mean ± RMSD (band) against imposed (dotted)")
    return _save(fig, path)


def plot_vectors(results: dict, path: Path, title: str = "") -> Path:
    """Fig. 6 (right): imposed and measured particle displacements at the peak frame,
    projected on the x–y and x–z planes."""
    plt = _plt()
    variant, a = next(iter(results.items()))
    v = a.arrays.get("vectors")
    fig, axs = plt.subplots(1, 2, figsize=(12, 4.5))
    if v is not None and len(v["X_um"]):
        X, t, m = v["X_um"], v["true_u"], v["meas_u"]
        # Arrows magnified so the largest imposed one spans 12 % of the field (as the paper's
        # overlays, the vectors are drawn at a scale of their own).
        extent = max(float(np.ptp(X[:, 0])), 1.0)
        gain = 0.12 * extent / max(float(np.linalg.norm(t, axis=1).max()), 1e-9)
        for ax, (i, j) in zip(axs, ((0, 1), (0, 2)), strict=True):
            kw = {"angles": "xy", "scale_units": "xy", "scale": 1.0 / gain, "width": 0.003}
            ax.quiver(X[:, i], X[:, j], t[:, i], t[:, j], color="k", label="imposed", **kw)
            ax.quiver(X[:, i], X[:, j], m[:, i], m[:, j], color="tab:red", label="measured", **kw)
            ax.set_xlabel(f"{AXES[i]} (µm)")
            ax.set_ylabel(f"{AXES[j]} (µm)")
            ax.set_aspect("equal", adjustable="datalim")
            ax.set_title(f"{AXES[i]}–{AXES[j]} projection, vectors × {gain:.3g}", fontsize=9)
        axs[0].legend(fontsize=7)
    peak = a.arrays.get("peak_frame", "?")
    fig.suptitle(title or f"Displacement vectors at frame {peak} ({LABEL.get(variant, variant)})")
    return _save(fig, path)


def plot_strain_history(results: dict, path: Path, title: str = "") -> Path:
    """Fig. 7: strain history (mean ± standard error) against time, with E_zz against the
    finite-deformation theory (E_zz = γ²/2 for simple shear)."""
    plt = _plt()
    fig, axs = plt.subplots(1, 2, figsize=(12, 4))
    for variant, a in results.items():
        t = _col(a.rows, "time_s")
        if not np.all(np.isfinite(t)):
            t = _col(a.rows, "frame")
        ls = STYLE.get(variant, "-")
        for c, color in (("xz", "tab:red"), ("xx", "tab:blue"), ("yy", "tab:orange")):
            mean = 100 * _col(a.rows, f"E_meas_{c}")
            se = 100 * _col(a.rows, f"E_se_{c}")
            axs[0].plot(t, mean, ls, color=color, label=f"E_{c}, {LABEL.get(variant, variant)}")
            axs[0].fill_between(t, mean - se, mean + se, color=color, alpha=0.25, lw=0)
            axs[0].plot(t, 100 * _col(a.rows, f"E_true_{c}"), "k:", lw=0.8)
        mean = 100 * _col(a.rows, "E_meas_zz")
        se = 100 * _col(a.rows, "E_se_zz")
        axs[1].plot(
            t, mean, ls, color="tab:green", label=f"measured, {LABEL.get(variant, variant)}"
        )
        axs[1].fill_between(t, mean - se, mean + se, color="tab:green", alpha=0.25, lw=0)
        axs[1].plot(t, 100 * _col(a.rows, "E_true_zz"), "k:", label="theory (γ²/2)")
    for ax in axs:
        ax.set_xlabel("time (s)")
        ax.set_ylabel("Lagrange strain (%)")
        ax.legend(fontsize=6)
    axs[0].set_title("strain history: mean ± standard error; dotted: imposed", fontsize=9)
    axs[1].set_title("E_zz against finite-deformation theory", fontsize=9)
    fig.suptitle(title or "Shear impact")
    return _save(fig, path)


def plot_slices(results: dict, path: Path, title: str = "") -> Path:
    """Fig. 7 (bottom): x–z slices (middle y) of the measured displacement u_x and strain E_xz
    at the peak frame next to the imposed ones."""
    plt = _plt()
    variant, a = next(iter(results.items()))
    f = a.arrays.get("field")
    fig, axs = plt.subplots(2, 2, figsize=(11, 6))
    if f is not None:
        fld = f["field"]
        j = len(fld.y_um) // 2
        ext = [fld.x_um[0], fld.x_um[-1], fld.z_um[0], fld.z_um[-1]]
        mask = fld.mask[:, j, :]
        ux = np.where(mask, fld.u[:, j, :, 0], np.nan)
        exz = np.where(mask, 100 * fld.E[:, j, :, 0, 2], np.nan)
        E_true = np.asarray(f["E_true"])
        if E_true.ndim == 2:
            exz_true = np.where(mask, 100 * E_true[0, 2], np.nan)
        else:
            full = np.full(fld.mask.shape, np.nan)
            full[fld.mask] = 100 * E_true[:, 0, 2]
            exz_true = full[:, j, :]
        motion = a.arrays.get("motion")
        Zg, Xg = np.meshgrid(fld.z_um, fld.x_um, indexing="ij")
        if motion is not None:
            pts = np.column_stack([Xg.ravel(), np.full(Xg.size, fld.y_um[j]), Zg.ravel()])
            ux_true = motion.displacement(pts, f["frame"])[:, 0].reshape(Xg.shape)
            ux_true = np.where(mask, ux_true, np.nan)
        else:
            ux_true = np.zeros_like(ux)
        lim_u = (np.nanmin([ux, ux_true]), np.nanmax([ux, ux_true]))
        lim_e = (np.nanmin([exz, exz_true]), np.nanmax([exz, exz_true]))
        for ax, img, name, lim in (
            (axs[0, 0], ux, "measured u_x (µm)", lim_u),
            (axs[0, 1], ux_true, "imposed u_x (µm)", lim_u),
            (axs[1, 0], exz, "measured E_xz (%)", lim_e),
            (axs[1, 1], exz_true, "imposed E_xz (%)", lim_e),
        ):
            im = ax.imshow(
                img,
                origin="lower",
                extent=ext,
                aspect="auto",
                cmap="viridis",
                vmin=lim[0],
                vmax=lim[1],
            )
            fig.colorbar(im, ax=ax)
            ax.set_title(name, fontsize=9)
            ax.set_xlabel("x (µm)")
            ax.set_ylabel("z (µm)")
        peak = f["frame"]
    else:
        peak = "?"
    fig.suptitle(title or f"x–z slices at y = middle, frame {peak} ({LABEL.get(variant, variant)})")
    fig.tight_layout()
    return _save(fig, path)
