"""Study files: an lfsim experiment TOML plus the sections that say how to validate it.

``hrvptm study EXPERIMENT.toml`` reads the experiment sections with :mod:`lfsim.experiment`
(which skips the three sections below) and these three here. Every key is checked; an
unknown one is an error naming the file, the section and the allowed keys. Relative paths
are relative to the TOML file's folder. Lengths in µm::

    [study]
    kind = "series"                # localization | pairs | series (default: series when the
                                   #   experiment has a [motion], localization otherwise)
    figure = "6c"                  # paper figure it rebuilds (its numbers go in the report)
    recon_scene = "../paper_4x.xml"  # forward model of the reconstruction: the one a user
                                   #   has for real data (default: the experiment's scene)
    matched = true                 # also run the matched model: render with recon_scene
    specimen_as_air = true         # also reconstruct the same frames as if the specimen were
                                   #   air (recon_scene without its interfaces): the error of
                                   #   a model that leaves the specimen out
    match_radius_um = 30           # largest distance of a detection from its true particle
    time_step_s = 0.002            # frame interval, for time axes (Fig. 7); default: none
    group_size = 2                 # pairs: frames per group of identical shots (Fig. 4c: 3)

    [recon]                        # recon.settings.ReconSettings: its fields, defaults
    z_min_um = 40                  #   and checks (unset: derived from the optics)
    z_max_um = 460
    z_step_um = 5
    s = 5
    iterations = 3

    [track]                        # track.series.SeriesSettings
    mode = "incremental"           # incremental | cumulative

    [track.detect]                 # track.detect.DetectSettings
    threshold = 0.25               # fraction of the intensity range (paper), or "auto"

    [track.grid]                   # track.fields.GridSettings
    target_nodes = 50000           # nodes of the gridded displacement and strain fields
    smoothing = "gcv"              # RBF smoothing: "gcv" or λ (0: exact)

    [track.link]                   # track.matching.LinkSettings

    [track.axial]                  # track.axial_bias.AxialCalibration
    method = "none"                # "simulated": subtract the reconstruction's bias measured
                                   # on simulated spheres at the detected positions
    sphere_diameter_um = 15        # the spheres: the particles' diameter (at most 1.5x from
                                   #   [particles] diameter_um)
    steps = 2                      # fixed-point steps: the second measures the bias again
                                   #   where the first put the particles (one more
                                   #   reference per frame; 1: the first step only)

Each section is a table (``[study]``, not ``study = "series"``); a section or key of
another type is an error naming it and what is expected. Every key of ``[recon]`` and
``[track…]`` is a field of the named settings dataclass, which
defines its default and its check once for the library, the command line and this file.

Kinds of study (what the truth is compared with):

``localization``
    every frame on its own: detected particle centres against the true ones (Fig. 4a);
``pairs``
    frames come in groups of ``group_size`` shots (``(0, 1), (2, 3), …`` for 2); the first of
    each group is linked to each other one; measured displacements against the true ones
    (zero-displacement pairs, Figs. 4b–c);
``series``
    the whole sequence is tracked from frame 0; cumulative displacements of the tracked
    particles and the gridded strain fields against the prescribed motion (Figs. 5–7).
"""

from __future__ import annotations

import dataclasses
import math
import os
import tomllib
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hrvbase.validate import check_table_keys
from recon.settings import ReconSettings
from track.axial_bias import AxialCalibration
from track.detect import DetectSettings
from track.fields import GridSettings
from track.matching import LinkSettings
from track.series import SeriesSettings

from .errors import StudyConfigError

KINDS = ("localization", "pairs", "series")
#: Paper figures a study may name (their numbers: :mod:`hrvptm.paper`).
FIGURES = ("4a", "4b", "4c", "5a", "5b", "6a", "6b", "6c", "7")


def _num(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def _int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _check_keys(where: str, section: str, table: Any, allowed) -> Mapping:
    return check_table_keys(where, section, table, allowed, error=StudyConfigError)


@dataclass(frozen=True)
class StudySpec:
    """The ``[study]`` section (see the module docstring)."""

    kind: str = "series"
    figure: str = ""
    recon_scene: Path | None = None
    matched: bool = False
    specimen_as_air: bool = False
    match_radius_um: float = 30.0
    time_step_s: float | None = None
    group_size: int = 2

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise StudyConfigError(f"kind must be one of {KINDS}, got {self.kind!r}")
        if self.figure and self.figure not in FIGURES:
            raise StudyConfigError(f"figure must be one of {FIGURES} or empty, got {self.figure!r}")
        if not isinstance(self.matched, bool):
            raise StudyConfigError(f"matched must be true or false, got {self.matched!r}")
        if not isinstance(self.specimen_as_air, bool):
            raise StudyConfigError(
                f"specimen_as_air must be true or false, got {self.specimen_as_air!r}"
            )
        if not _num(self.match_radius_um) or self.match_radius_um <= 0:
            raise StudyConfigError(
                f"match_radius_um must be a number > 0 (µm), got {self.match_radius_um!r}"
            )
        if self.time_step_s is not None and (not _num(self.time_step_s) or self.time_step_s <= 0):
            raise StudyConfigError(
                f"time_step_s must be a number > 0 (s), got {self.time_step_s!r}"
            )
        if not _int(self.group_size) or self.group_size < 2:
            raise StudyConfigError(f"group_size must be an integer >= 2, got {self.group_size!r}")
        if self.recon_scene is not None:
            object.__setattr__(self, "recon_scene", Path(self.recon_scene))


#: The variant that reconstructs the frames as if the specimen were air.
AS_AIR = "as_air"

#: Keys of ``[study]``.
STUDY_KEYS = tuple(f.name for f in dataclasses.fields(StudySpec))

#: Sub-tables of ``[track]`` and the settings dataclass each one builds (its keys are the
#: dataclass's fields; ``[track]`` itself holds the scalar fields of SeriesSettings).
TRACK_TABLES = {
    "detect": DetectSettings,
    "grid": GridSettings,
    "link": LinkSettings,
    "axial": AxialCalibration,
}


@dataclass(frozen=True)
class TrackSpec:
    """The ``[track]`` section: the track settings of the study.

    Attributes
    ----------
    detect : track.detect.DetectSettings
        ``[track.detect]``.
    series : track.series.SeriesSettings
        ``[track]`` (``mode``, ``min_particles``) with ``[track.grid]`` and ``[track.link]``.
    axial : track.axial_bias.AxialCalibration
        ``[track.axial]``: the simulator self-calibration of the reconstruction's bias
        (default off).
    """

    detect: DetectSettings = field(default_factory=DetectSettings)
    series: SeriesSettings = field(default_factory=lambda: SeriesSettings(link=LinkSettings()))
    axial: AxialCalibration = field(default_factory=AxialCalibration)


@dataclass(frozen=True)
class Study:
    """A validated study: the lfsim experiment and how to reconstruct, track and compare it.

    Attributes
    ----------
    experiment : lfsim.experiment.Experiment
        Rendered as given (the no-inverse-crime dataset when its scene has glass lenslets).
    study : StudySpec
    recon : recon.settings.ReconSettings
    track : TrackSpec
    source : Path or None
        The TOML file.
    """

    experiment: Any
    study: StudySpec = field(default_factory=StudySpec)
    recon: ReconSettings = field(default_factory=ReconSettings)
    track: TrackSpec = field(default_factory=TrackSpec)
    source: Path | None = None

    @property
    def name(self) -> str:
        return self.experiment.name

    @property
    def recon_scene(self) -> Path:
        """Scene whose optics the reconstruction uses."""
        return self.study.recon_scene or self.experiment.scene

    def variants(self) -> dict[str, Any]:
        """Datasets to run, by variant name.

        ``"mismatched"``: the experiment as given, rendered with another model than the
        reconstruction's (``"matched"`` when its scene is ``recon_scene`` itself); with
        ``matched = true`` also ``"matched"``: the same experiment rendered through
        ``recon_scene``, the forward model of the reconstruction; with ``specimen_as_air =
        true`` also ``"as_air"``: the first variant's frames (not rendered again)
        reconstructed with ``recon_scene`` as if its specimen were air
        (:func:`hrvptm.stages.recon_optics`)."""
        first = "mismatched" if self.is_crime_free else "matched"
        out = {first: self.experiment}
        if self.study.matched and self.is_crime_free:
            render = self.experiment.render
            if self.renders_other_model:
                render = dataclasses.replace(render, model="ray")
            out["matched"] = dataclasses.replace(
                self.experiment, scene=self.recon_scene, optics=None, render=render
            )
        if self.study.specimen_as_air:
            out[AS_AIR] = self.experiment
        return out

    def dataset_variant(self, variant: str) -> str:
        """The variant whose rendered dataset ``variant`` reconstructs (itself, but for
        ``"as_air"``, which reuses the first variant's frames)."""
        if variant == AS_AIR:
            return "mismatched" if self.is_crime_free else "matched"
        return variant

    @property
    def is_crime_free(self) -> bool:
        """True when the images are rendered with another model than the reconstruction's:
        through another scene, or with the wave model (``[render] model = "wave"``) for a
        reconstruction with the ray bank (:attr:`renders_other_model`)."""
        a = Path(self.experiment.scene).resolve()
        b = Path(self.recon_scene).resolve()
        return a != b or self.renders_other_model

    @property
    def renders_other_model(self) -> bool:
        """True when the frames are rendered with the wave model and reconstructed with the
        ray PSF bank (``[recon] psf_model`` resolved by
        :func:`recon.psf_wave.choose_psf_model` for ``recon_scene``'s optics)."""
        if self.experiment.render.model != "wave":
            return False
        from lfsim.scene import read_optics
        from recon.psf_wave import choose_psf_model

        return choose_psf_model(read_optics(self.recon_scene), self.recon.psf_model) == "ray"

    def to_dict(self) -> dict:
        """Plain-JSON form (for the report and the stage fingerprints)."""

        def clean(d):
            return {k: (str(v) if isinstance(v, Path) else v) for k, v in d.items()}

        return {
            "experiment": self.experiment.to_dict(),
            "study": clean(dataclasses.asdict(self.study)) | {"recon_scene": str(self.recon_scene)},
            "recon": self.recon.to_dict(),
            "track": dataclasses.asdict(self.track),
        }


_TYPE_WORDS = {int: "an integer", float: "a number", str: "a string", bool: "true or false"}


def _expected_type(value: Any, hint: Any) -> str | None:
    """What a TOML value of a field typed ``hint`` should be, or None when ``value`` fits.

    Only the kinds of value TOML has are checked (numbers, strings, booleans, arrays); the
    dataclass checks the values themselves."""
    if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union:
        words = []
        for member in typing.get_args(hint):
            if member is type(None):
                continue
            word = _expected_type(value, member)
            if word is None:
                return None
            words.append(word)
        return " or ".join(dict.fromkeys(words)) or None
    if hint is Path:
        return None if isinstance(value, str | Path) else "a path (a string)"
    if hint is tuple or typing.get_origin(hint) is tuple:
        args = typing.get_args(hint)
        fixed = bool(args) and Ellipsis not in args
        words = f"a list of {len(args)} values" if fixed else "a list"
        if not isinstance(value, list | tuple):
            return words
        if fixed and (
            len(value) != len(args)
            or any(_expected_type(v, a) for v, a in zip(value, args, strict=False))
        ):
            return f"{words} ({', '.join(_TYPE_WORDS.get(a, 'a value') for a in args)})"
        return None
    if hint in _TYPE_WORDS:
        ok = {
            int: lambda v: isinstance(v, int) and not isinstance(v, bool),
            float: lambda v: isinstance(v, int | float) and not isinstance(v, bool),
            str: lambda v: isinstance(v, str),
            bool: lambda v: isinstance(v, bool),
        }[hint](value)
        return None if ok else _TYPE_WORDS[hint]
    return None  # nested settings and the like: the dataclass checks them


def _settings(cls, where: str, name: str, table: Mapping | None, skip=(), **extra):
    """The settings dataclass ``cls`` from a TOML table: its keys are the dataclass's fields
    (``skip`` excepted), of the fields' types; its defaults and checks the dataclass's own."""
    from hrvbase.errors import HrvError

    allowed = tuple(f.name for f in dataclasses.fields(cls) if f.name not in skip)
    tab = dict(_check_keys(where, name, table or {}, allowed))
    hints = typing.get_type_hints(cls)
    for key, value in tab.items():
        expected = _expected_type(value, hints.get(key))
        if expected is not None:
            raise StudyConfigError(f"{where}: [{name}] {key} must be {expected}, got {value!r}")
    try:
        return cls(**tab, **extra)
    except (HrvError, TypeError, ValueError) as exc:  # a value the dataclass cannot take
        raise StudyConfigError(f"{where}: [{name}] {exc}") from None


def _study_spec(where: str, table: Mapping, base: Path) -> StudySpec:
    tab = dict(table)
    if "recon_scene" in tab:
        p = Path(tab["recon_scene"])
        tab["recon_scene"] = p if p.is_absolute() else (base / p).resolve()
        if not tab["recon_scene"].is_file():
            raise StudyConfigError(
                f"{where}: [study] recon_scene {str(tab['recon_scene'])!r} does not exist"
            )
    return _settings(StudySpec, where, "study", tab)


def _track_spec(where: str, table: Mapping | None) -> TrackSpec:
    skip = ("grid", "link", "compute_fields")
    allowed = [f.name for f in dataclasses.fields(SeriesSettings) if f.name not in skip]
    table = dict(_check_keys(where, "track", table or {}, [*allowed, *TRACK_TABLES]))
    sub = {k: table.pop(k) for k in TRACK_TABLES if k in table}
    detect = _settings(DetectSettings, where, "track.detect", sub.get("detect"))
    grid = _settings(GridSettings, where, "track.grid", sub.get("grid"))
    link = _settings(LinkSettings, where, "track.link", sub.get("link"))
    axial = _settings(AxialCalibration, where, "track.axial", sub.get("axial"))
    series = _settings(
        SeriesSettings,
        where,
        "track",
        table,
        skip=skip,
        grid=grid,
        link=link,
    )
    return TrackSpec(detect=detect, series=series, axial=axial)


def study_from_dict(
    data: Mapping, base_dir: str | os.PathLike | None = None, source: str | None = None
) -> Study:
    """Build a :class:`Study` from a parsed TOML table (see the module docstring)."""
    from hrvbase.errors import HrvError
    from lfsim.experiment import Experiment

    where = source or "study"
    base = Path(base_dir) if base_dir is not None else Path.cwd()
    if not isinstance(data, Mapping):
        raise StudyConfigError(f"{where}: expected a table of sections")
    try:
        exp = Experiment.from_dict(data, base_dir=base, source=source)
    except HrvError as exc:
        raise StudyConfigError(str(exc)) from None
    spec = data.get("study")
    if spec is not None and not isinstance(spec, Mapping):
        hint = (
            f" (write [study] with kind = {spec!r})"
            if isinstance(spec, str) and spec in KINDS
            else ""
        )
        raise StudyConfigError(
            f"{where}: [study] must be a table of the keys {', '.join(STUDY_KEYS)}{hint}, "
            f"got {type(spec).__name__} {spec!r}"
        )
    if spec is not None and "kind" not in spec:
        spec = {**spec, "kind": "series" if exp.motion is not None else "localization"}
    if spec is None:
        spec = {"kind": "series" if exp.motion is not None else "localization"}
    st = _study_spec(where, spec, base)
    rc = _settings(ReconSettings, where, "recon", data.get("recon"))
    tr = _track_spec(where, data.get("track"))
    if st.kind == "pairs" and exp.frames % st.group_size:
        raise StudyConfigError(
            f"{where}: a 'pairs' study needs a multiple of group_size = {st.group_size} frames "
            f"(groups of identical shots), got frames = {exp.frames}"
        )
    if st.kind == "series" and exp.frames < 2:
        raise StudyConfigError(f"{where}: a 'series' study needs frames >= 2, got {exp.frames}")
    study = Study(exp, st, rc, tr, Path(source) if source else None)
    _check_recon_scene(where, study)
    _check_sphere_diameter(where, study)
    return study


#: ``[track.axial] sphere_diameter_um`` may differ from ``[particles] diameter_um`` by at most
#: this factor either way: the reference spheres are the particles.
SPHERE_TOLERANCE = 1.5


def _check_sphere_diameter(where: str, study: Study) -> None:
    """Refuse reference spheres of another size than the particles the study seeds (a table
    of particles, ``kind = "csv"``, is checked on the volumes, by
    :func:`hrvptm.calibrated.check_sphere_diameter`)."""
    from .calibrated import reference_settings

    axial, seeding = study.track.axial, study.experiment.particles
    if not axial.enabled or seeding.kind == "csv":
        return
    d, p = reference_settings(axial).sphere_diameter_um, seeding.diameter_um
    if not p / SPHERE_TOLERANCE <= d <= p * SPHERE_TOLERANCE:
        key = (
            "sphere_diameter_um"
            if axial.sphere_diameter_um is not None
            else ("sphere_diameter_um (unset: the default)")
        )
        raise StudyConfigError(
            f"{where}: [track.axial] {key} = {d:g} µm is not the particles' diameter "
            f"([particles] diameter_um = {p:g} µm; at most {SPHERE_TOLERANCE:g}× apart): the "
            f"reference spheres are the particles, give sphere_diameter_um = {p:g}"
        )


def _check_recon_scene(where: str, study: Study) -> None:
    """Refuse, before any work, a reconstruction model of another microscope than the
    experiment's (only the lenslet model may differ: glass vs ideal), and a
    ``[track.grid] spacing_um`` that gives far too many nodes over the volumes."""
    from hrvbase.errors import HrvError
    from lfsim.scene import read_optics
    from recon.pipeline import optics_differences
    from track.series import check_grid

    optics = read_optics(study.recon_scene)
    diffs = optics_differences(
        optics, study.experiment.optics, labels=("recon_scene", "experiment scene")
    )
    if diffs:
        raise StudyConfigError(
            f"{where}: [study] recon_scene {str(study.recon_scene)!r} is another microscope "
            f"than the experiment's scene {str(study.experiment.scene)!r}: {'; '.join(diffs)}; "
            "a study reconstructs with the optics it renders with (only the lenslet model, "
            "glass or ideal, may differ)"
        )
    if study.study.specimen_as_air and not optics.has_interfaces:
        raise StudyConfigError(
            f"{where}: [study] specimen_as_air = true, but recon_scene "
            f"{str(study.recon_scene)!r} has no specimen to leave out (medium_ior = "
            f"immersion_ior = {optics.immersion_ior:g}, no cover glass)"
        )
    grid = study.track.series.grid
    if study.study.kind != "series" or grid.spacing_um is None or study.recon.roi_xy_px is not None:
        return
    try:
        depths = study.recon.resolved(optics).depths_um
    except HrvError as exc:
        raise StudyConfigError(f"{where}: [recon] {exc}") from None
    # A lower bound of the volumes' size (x, y, z): rectification keeps at least the whole
    # lenslets but two, less one voxel.
    whole = np.floor(np.asarray(optics.sensor_xy_px) / optics.px_per_lenslet) - 3
    lower = [*(np.maximum(whole, 0) * optics.lenslet_object_um), depths[-1] - depths[0]]
    if grid.spacing_um < max(lower):  # the single-cell check needs the exact size: later
        try:
            check_grid(
                lower,
                grid,
                where="a lower bound of the reconstructed volumes",
                spacing_name="[track.grid] spacing_um",
            )
        except HrvError as exc:
            raise StudyConfigError(f"{where}: {exc}") from None


def load_study(path: str | os.PathLike) -> Study:
    """Read and validate a study (experiment) TOML file.

    Raises
    ------
    StudyConfigError
        Missing or invalid file, unknown section or key, or an invalid value (the message names
        the file, the section and what was expected).
    """
    path = Path(path)
    data = _read_toml(path, "study file")
    return study_from_dict(data, base_dir=path.parent.resolve(), source=str(path))


def _read_toml(path: Path, what: str) -> dict:
    if not path.is_file():
        raise StudyConfigError(f"{what} {str(path)!r} does not exist")
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise StudyConfigError(f"{path}: not valid TOML: {exc}") from None


def load_track_config(path: str | os.PathLike | None) -> TrackSpec:
    """The track settings of a file holding only ``[track]`` tables, as in a study file
    (``hrvptm axial --track-config``); None: the defaults.

    Raises
    ------
    StudyConfigError
        Missing or invalid file, a table other than ``[track]``, or an invalid value (the
        message names the file and the section).
    """
    if path is None:
        return TrackSpec()
    path = Path(path)
    data = _read_toml(path, "track config")
    other = sorted(set(data) - {"track"})
    if other:
        raise StudyConfigError(f"{path}: only [track] tables belong here, not {other}")
    return _track_spec(str(path), data.get("track"))
