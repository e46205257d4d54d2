"""Experiment files: one TOML describes a whole synthetic light-field experiment.

An experiment names a scene (the optics), how to seed the reference particles, how they move
from frame to frame, how each frame is traced and made camera-like, and the white
(flat-field) calibration image. :func:`load_experiment` reads and validates it into a frozen
:class:`Experiment`; :func:`lfsim.dataset.generate_dataset` turns that into files.

Schema (every section and key is checked; an unknown or misspelt one is an error naming the
key, the file and the allowed keys; relative paths are relative to the TOML file's folder)::

    [experiment]
    name = "simple_shear_test"     # required
    scene = "../small.xml"         # required: an lfsim scene file (lfsim.scene.write_scene)
    seed = 1                        # default 0: seeds particles, rays and noise
    frames = 6                      # default 1; frame 0 is the reference configuration
    description = "..."            # optional free text

    [particles]                     # required: lfsim.seeding.SeedingSpec
    kind = "box"                    # box | layer | csv
    count = 12                      # or density_per_mm3
    bounds_xyz_um = [[-200, 180], [-200, 180], [100, 400]]
    # z_um (layer), min_spacing_um, diameter_um (15), brightness (1), brightness_jitter (0),
    # csv (kind = "csv": a particle table)

    [motion]                        # optional (no section: every frame is the reference)
    type = "simple_shear"           # translation | rotation | uniaxial_tension | simple_shear
    plane = "xz"                    #   | gaussian_indentation | stiff_inclusion | user_field;
    step_gamma = 0.025              #   keys of lfsim.motion's classes; an explicit `values`
                                    #   schedule needs one value per frame
    center_xyz_um = [0, 0, 250]

    [render]
    rays_per_particle = 100000      # rays (= photons) per particle of brightness 1
    tracer = "mitsuba"              # mitsuba | paraxial (ideal lenslets only)
    model = "ray"                   # ray | wave (scalar wave optics, ideal lenslets only)
    diffraction = true
    batch_rays = 4194304            # rays per kernel launch (memory bound)

    [noise]                         # lfsim.noise.NoiseSpec; default model "gaussian", snr 17
    model = "gaussian"              # none | gaussian | camera
    snr = 17                        # or a list, one value per frame (SNR sweeps, Fig. 4a/4b)
    # bit_depth, fill, offset_sigmas, duty_cycle, photon_rate_per_s, camera = {...},
    # fps (model camera; a number or a list, one value per frame: frame-rate sweep, Fig. 4c)

    [white]                         # flat-field image through the same optics
    rays_per_lenslet = 20000
    snr = 50
    bit_depth = 16
    enabled = true

    [study], [recon], [track]       # not read here: settings of ``hrvptm study`` (validation)

SNR is the paper's ``P99.9(clean image) / sigma_noise`` with ``P99.9`` the 99.9th percentile of
the noise-free image (docs/conventions.md).
"""

from __future__ import annotations

import difflib
import hashlib
import json
import math
import numbers
import os
import tomllib
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from hrvbase.validate import check_table_keys

from .camera import BIT_DEPTHS
from .errors import ConfigError
from .motion import Motion, UserField, _is_path, motion_from_dict
from .noise import NoiseSpec
from .optics import Optics
from .render import TRACERS, WHITE_RAYS_PER_LENSLET
from .scene import read_optics
from .seeding import SeedingSpec
from .tracer import RenderSettings

#: Allowed keys of each section (``particles``/``noise`` mirror their dataclasses).
EXPERIMENT_KEYS = ("name", "scene", "seed", "frames", "description")
RENDER_KEYS = ("rays_per_particle", "tracer", "diffraction", "batch_rays", "model")
WHITE_KEYS = ("rays_per_lenslet", "snr", "bit_depth", "enabled")
PARTICLE_KEYS = tuple(f.name for f in fields(SeedingSpec))
NOISE_KEYS = tuple(f.name for f in fields(NoiseSpec))
SECTIONS = ("experiment", "particles", "motion", "render", "noise", "white")
#: Sections read by the tools downstream of the simulator (``hrvptm study``: the validation
#: study, the reconstruction and the tracking settings). lfsim skips them; they are not part
#: of the dataset it makes (nor of its fingerprint).
DOWNSTREAM_SECTIONS = ("study", "recon", "track")
#: Noise keys that may be a list with one value per frame.
PER_FRAME_NOISE_KEYS = ("snr", "fps")

#: Names under which :meth:`Experiment.fingerprint` hashes the keys named otherwise in the
#: API (docs/conventions.md §3): the fingerprint identifies what an experiment produces, and a
#: key's name does not change that, so the datasets already made keep theirs.
FINGERPRINT_KEYS = {"center_xyz_um": "center_um", "bounds_xyz_um": "box_um"}

#: Noise model when the file has no ``[noise]`` section: the paper's default (§4).
DEFAULT_NOISE = {"model": "gaussian", "snr": 17.0}


# -- small validators ------------------------------------------------------------------------
def _is_int(v: Any) -> bool:
    return isinstance(v, int | np.integer) and not isinstance(v, bool)


def _is_num(v: Any) -> bool:
    return isinstance(v, numbers.Real) and not isinstance(v, bool)


def _check_keys(where: str, section: str, table: Any, allowed) -> Mapping:
    return check_table_keys(where, section, table, allowed, error=ConfigError)


@dataclass(frozen=True)
class RenderConfig:
    """The ``[render]`` section: how every frame is traced.

    ``rays_per_particle`` rays (photons into the collection cone) per particle of brightness 1,
    tracer ``"mitsuba"`` or ``"paraxial"``, Gaussian diffraction blur on/off, rays per kernel
    launch. Frames are traced in mode ``"photons"`` (integer counts, bit-identical per seed).
    ``model`` ``"wave"`` renders the particles with the wave-optics model instead
    (:mod:`lfsim.wave_render`: Poisson counts of ``rays_per_particle`` expected photons per
    unit brightness; ideal lenslets only); the white image is traced in either case.
    """

    rays_per_particle: int = RenderSettings.rays_per_particle
    tracer: str = "mitsuba"
    diffraction: bool = RenderSettings.diffraction
    batch_rays: int = RenderSettings.batch_rays
    model: str = RenderSettings.model

    def __post_init__(self) -> None:
        if self.tracer not in TRACERS:
            raise ConfigError(f"tracer must be one of {TRACERS}, got {self.tracer!r}")
        if not isinstance(self.diffraction, bool):
            raise ConfigError(f"diffraction must be true or false, got {self.diffraction!r}")
        for name in ("rays_per_particle", "batch_rays"):
            if not _is_int(getattr(self, name)):
                raise ConfigError(f"{name} must be an integer, got {getattr(self, name)!r}")
        self.settings(0)  # validates the numbers

    def settings(self, seed: int) -> RenderSettings:
        """The :class:`RenderSettings` of one frame (photon mode)."""
        return RenderSettings(
            rays_per_particle=int(self.rays_per_particle),
            mode="photons",
            diffraction=self.diffraction,
            seed=int(seed),
            batch_rays=int(self.batch_rays),
            model=self.model,
        )


@dataclass(frozen=True)
class WhiteConfig:
    """The ``[white]`` section: the flat-field image (uniformly fluorescent slide).

    ``rays_per_lenslet`` rays per lenslet footprint, Gaussian noise of ``snr``
    (``P99.9(clean) / sigma``), ``bit_depth`` bits (16 → uint16), ``enabled`` to write it.
    """

    rays_per_lenslet: int = WHITE_RAYS_PER_LENSLET
    snr: float = 50.0
    bit_depth: int = 16
    enabled: bool = True

    def __post_init__(self) -> None:
        if not _is_int(self.rays_per_lenslet) or self.rays_per_lenslet < 1:
            raise ConfigError(
                f"rays_per_lenslet must be a positive integer, got {self.rays_per_lenslet!r}"
            )
        if not _is_num(self.snr) or not math.isfinite(self.snr) or self.snr <= 0:
            raise ConfigError(f"snr must be a positive number, got {self.snr!r}")
        object.__setattr__(self, "snr", float(self.snr))
        if not _is_int(self.bit_depth) or self.bit_depth not in BIT_DEPTHS:
            raise ConfigError(f"bit_depth must be one of {BIT_DEPTHS}, got {self.bit_depth!r}")
        if not isinstance(self.enabled, bool):
            raise ConfigError(f"enabled must be true or false, got {self.enabled!r}")


# -- the experiment --------------------------------------------------------------------------
@dataclass(frozen=True)
class Experiment:
    """A validated synthetic experiment (see the module docstring for the file format).

    Attributes
    ----------
    name : str
    scene : Path
        Absolute path of the scene file.
    particles : SeedingSpec
        How the reference particles are made (seeded with ``numpy.random.default_rng(seed)``).
    frames : int
        Number of frames; frame 0 is the reference configuration.
    seed : int
    description : str
    motion : Motion or None
        Prescribed motion (``None``: all frames identical).
    render : RenderConfig
    noise : tuple of NoiseSpec
        One per frame (use :meth:`noise_for_frame`).
    white : WhiteConfig
    optics : Optics
        The scene's optics (read from the scene file).
    source : Path or None
        The TOML file it was read from (not part of equality or the fingerprint).
    """

    name: str
    scene: Path
    particles: SeedingSpec
    frames: int = 1
    seed: int = 0
    description: str = ""
    motion: Motion | None = None
    render: RenderConfig = field(default_factory=RenderConfig)
    noise: tuple[NoiseSpec, ...] = ()
    white: WhiteConfig = field(default_factory=WhiteConfig)
    optics: Optics | None = None
    source: Path | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip():
            raise ConfigError(f"name must be a non-empty string, got {self.name!r}")
        if not _is_int(self.frames) or self.frames < 1:
            raise ConfigError(f"frames must be an integer >= 1, got {self.frames!r}")
        if not _is_int(self.seed) or self.seed < 0:
            raise ConfigError(f"seed must be an integer >= 0, got {self.seed!r}")
        if not isinstance(self.description, str):
            raise ConfigError(f"description must be a string, got {self.description!r}")
        object.__setattr__(self, "scene", Path(self.scene))
        noise = tuple(self.noise) or (NoiseSpec(**DEFAULT_NOISE),)
        if len(noise) == 1:
            noise = noise * self.frames
        if len(noise) != self.frames or not all(isinstance(n, NoiseSpec) for n in noise):
            raise ConfigError(
                f"noise must hold one NoiseSpec per frame ({self.frames}), got {len(noise)}"
            )
        object.__setattr__(self, "noise", noise)
        if self.optics is None:
            object.__setattr__(self, "optics", read_optics(self.scene))
        if self.render.tracer == "paraxial" and self.optics.mla_kind != "ideal":
            raise ConfigError(
                f"tracer 'paraxial' models ideal lenslets only, but {self.scene} has a "
                f"{self.optics.mla_kind!r} microlens array; use tracer 'mitsuba'"
            )
        if self.render.model == "wave" and self.optics.mla_kind != "ideal":
            raise ConfigError(
                f"[render] model 'wave' models ideal lenslets only, but {self.scene} has a "
                f"{self.optics.mla_kind!r} microlens array; use model 'ray'"
            )
        n_sched = getattr(self.motion, "n_frames", None)
        if n_sched is not None and n_sched != self.frames:
            raise ConfigError(
                f"the motion's 'values' schedule has {n_sched} entries but frames = "
                f"{self.frames}; give one value per frame"
            )

    # -- construction --------------------------------------------------------------------
    @classmethod
    def from_dict(
        cls,
        data: Mapping,
        base_dir: str | os.PathLike | None = None,
        source: str | os.PathLike | None = None,
    ) -> Experiment:
        """Build and validate from the parsed TOML (or from :meth:`to_dict`'s output).

        Parameters
        ----------
        data : Mapping
            Sections as in the module docstring.
        base_dir : path, optional
            Folder that relative paths (scene, particle csv, user-field files) are relative to.
        source : path, optional
            File name used in error messages (and kept as :attr:`source`).
        """
        where = str(source) if source is not None else "experiment"
        base = Path(base_dir) if base_dir is not None else Path.cwd()
        _check_sections(where, data)
        exp, scene, optics, frames = _experiment_section(where, data["experiment"], base)
        particles = _particles_section(where, data["particles"], base)
        motion = _motion_section(where, data.get("motion"), base, frames)
        rtab = _check_keys(where, "render", data.get("render", {}), RENDER_KEYS)
        try:
            render = RenderConfig(**rtab)
        except ConfigError as exc:
            raise _fail(where, "render", exc) from exc
        noise = _noise_section(where, data.get("noise", DEFAULT_NOISE), frames)
        wtab = _check_keys(where, "white", data.get("white", {}), WHITE_KEYS)
        try:
            white = WhiteConfig(**wtab)
        except ConfigError as exc:
            raise _fail(where, "white", exc) from exc
        try:
            return cls(
                name=exp["name"],
                scene=scene,
                particles=particles,
                frames=frames,
                seed=exp.get("seed", 0),
                description=exp.get("description", ""),
                motion=motion,
                render=render,
                noise=noise,
                white=white,
                optics=optics,
                source=Path(source) if source is not None else None,
            )
        except ConfigError as exc:
            raise _fail(where, "experiment", exc) from exc

    # -- queries ---------------------------------------------------------------------------
    def noise_for_frame(self, k: int) -> NoiseSpec:
        """The noise model of frame ``k`` (per-frame ``snr``/``fps`` lists resolved)."""
        if not _is_int(k) or not (0 <= k < self.frames):
            raise ConfigError(f"frame must be an integer in [0, {self.frames}), got {k!r}")
        return self.noise[int(k)]

    def positions(self, reference_um: np.ndarray, k: int) -> np.ndarray:
        """Particle positions (N, 3) µm at frame ``k``: ``motion.positions(X_ref, k)``."""
        if not _is_int(k) or not (0 <= k < self.frames):
            raise ConfigError(f"frame must be an integer in [0, {self.frames}), got {k!r}")
        X = np.asarray(reference_um, dtype=np.float64)
        if self.motion is None:
            return X.copy()
        return self.motion.positions(X, int(k))

    def to_dict(self) -> dict:
        """Canonical plain-JSON form: every default filled in, per-frame noise values as lists
        (only where they vary). :meth:`from_dict` accepts it back."""
        base = self.noise[0].to_dict()
        for key in PER_FRAME_NOISE_KEYS:
            vals = [getattr(n, key) for n in self.noise]
            if any(v != vals[0] for v in vals):
                base[key] = vals
        return {
            "experiment": {
                "name": self.name,
                "scene": str(self.scene),
                "seed": int(self.seed),
                "frames": int(self.frames),
                "description": self.description,
            },
            "particles": self.particles.to_dict(),
            "motion": None if self.motion is None else self.motion.to_dict(),
            "render": asdict(self.render),
            "noise": base,
            "white": asdict(self.white),
        }

    def fingerprint(self) -> str:
        """SHA-256 identifying what this experiment produces.

        Hash of the canonical dict (:meth:`to_dict`, its keys named as in
        :data:`FINGERPRINT_KEYS`) with file locations replaced by the
        files' contents (the scene file's SHA-256, and those of a particle CSV or user-field
        module), plus ``lfsim.__version__``. Moving the files elsewhere keeps the
        fingerprint; editing any of them changes it.
        """
        from hrvbase.io import rename_keys

        from . import __version__
        from .io import sha256_file

        d = rename_keys(self.to_dict(), FINGERPRINT_KEYS)
        del d["experiment"]["scene"]
        if d["render"]["model"] == RenderSettings.model:
            del d["render"]["model"]  # the ray model's datasets keep their fingerprint
        if self.particles.kind == "csv":
            d["particles"]["csv"] = "sha256:" + sha256_file(self.particles.csv)
        if isinstance(self.motion, UserField):
            module, _, func = self.motion.function.rpartition(":")
            if _is_path(module):
                d["motion"]["function"] = f"sha256:{sha256_file(module)}:{func}"
        payload = {
            "experiment": d,
            "scene_sha256": sha256_file(self.scene),
            "lfsim_version": __version__,
        }
        text = json.dumps(payload, sort_keys=True, separators=(",", ":"), allow_nan=False)
        return hashlib.sha256(text.encode()).hexdigest()


def _fail(where: str, section: str, exc: Exception) -> ConfigError:
    """The error of section ``section`` of experiment file ``where``."""
    return ConfigError(f"{where}: [{section}]: {exc}")


def _check_sections(where: str, data) -> None:
    """Refuse a file that is not a table, has an unknown section (naming the nearest) or
    lacks [experiment] or [particles]."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where}: expected a table of sections, got {type(data).__name__}")
    for key in data:
        if key in DOWNSTREAM_SECTIONS:
            continue
        if key not in SECTIONS:
            hint = difflib.get_close_matches(str(key), SECTIONS + DOWNSTREAM_SECTIONS, n=1)
            did = f" (did you mean [{hint[0]}]?)" if hint else ""
            raise ConfigError(
                f"{where}: unknown section or key [{key}]{did}; allowed sections: "
                f"{', '.join(f'[{s}]' for s in SECTIONS)}"
            )
    for req in ("experiment", "particles"):
        if req not in data:
            raise ConfigError(f"{where}: missing required section [{req}]")


def _experiment_section(where: str, table, base: Path) -> tuple:
    """The [experiment] table checked, its scene file (absolute), the scene's optics and the
    number of frames."""
    exp = _check_keys(where, "experiment", table, EXPERIMENT_KEYS)
    for req in ("name", "scene"):
        if req not in exp:
            raise ConfigError(f"{where}: [experiment] needs the key {req!r}")
    if not isinstance(exp["scene"], str | os.PathLike):
        raise ConfigError(f"{where}: [experiment] scene must be a path, got {exp['scene']!r}")
    scene = Path(exp["scene"])
    if not scene.is_absolute():
        scene = base / scene
    scene = scene.resolve()
    if not scene.is_file():
        raise ConfigError(
            f"{where}: [experiment] scene: the scene file {scene} does not exist "
            f"(write one with `lfsim scene`)"
        )
    try:
        optics = read_optics(scene)
    except ConfigError as exc:
        raise _fail(where, "experiment", exc) from exc
    frames = exp.get("frames", 1)
    if not _is_int(frames) or frames < 1:
        raise ConfigError(f"{where}: [experiment] frames must be an integer >= 1, got {frames!r}")
    return exp, scene, optics, frames


def _particles_section(where: str, table, base: Path) -> SeedingSpec:
    """The seeding of the [particles] table (a csv table must exist; at least 1 particle)."""
    ptab = _check_keys(where, "particles", table, PARTICLE_KEYS)
    try:
        particles = SeedingSpec.from_dict(ptab, base_dir=base)
    except ConfigError as exc:
        raise _fail(where, "particles", exc) from exc
    if particles.kind == "csv" and not Path(particles.csv).is_file():
        raise ConfigError(
            f"{where}: [particles] csv: the particle table {particles.csv} does not exist"
        )
    if particles.n_particles == 0:
        key = "count" if particles.count is not None else "density_per_mm3"
        raise ConfigError(
            f"{where}: [particles] {key} = {ptab[key]!r} seeds no particles; expected at least 1"
        )
    return particles


def _motion_section(where: str, mtab, base: Path, frames: int) -> Motion | None:
    """The motion of the [motion] table (None without one); a ``values`` schedule must have
    one entry per frame."""
    if mtab is None:
        return None
    if not isinstance(mtab, Mapping):
        raise ConfigError(f"{where}: [motion] must be a table, got {mtab!r}")
    try:
        motion = motion_from_dict(mtab, base_dir=base)
    except ConfigError as exc:
        raise _fail(where, "motion", exc) from exc
    n_sched = getattr(motion, "n_frames", None)
    if n_sched is not None and n_sched != frames:
        raise ConfigError(
            f"{where}: [motion] values has {n_sched} entries but [experiment] frames = "
            f"{frames}; give one value per frame"
        )
    return motion


def _noise_section(where: str, table, frames: int) -> tuple[NoiseSpec, ...]:
    """The noise model of every frame from the [noise] table (per-frame lists of
    :data:`PER_FRAME_NOISE_KEYS` resolved)."""
    ntab = dict(_check_keys(where, "noise", table, NOISE_KEYS))
    if "camera" in ntab and isinstance(ntab["camera"], Mapping):
        ntab["camera"] = dict(ntab["camera"])
    per_frame: dict[str, list] = {}
    for key in PER_FRAME_NOISE_KEYS:
        v = ntab.get(key)
        if isinstance(v, list | tuple):
            if len(v) != frames:
                raise ConfigError(
                    f"{where}: [noise] {key} has {len(v)} values but [experiment] frames = "
                    f"{frames}; give one value per frame or a single number"
                )
            per_frame[key] = list(v)
    noise = []
    for k in range(frames):
        d = dict(ntab)
        for key, vals in per_frame.items():
            d[key] = vals[k]
        try:
            noise.append(NoiseSpec.from_dict(d))
        except ConfigError as exc:
            at = f" (frame {k})" if per_frame else ""
            raise ConfigError(f"{where}: [noise]{at}: {exc}") from exc
    return tuple(noise)


def load_experiment(path: str | os.PathLike) -> Experiment:
    """Read and validate an experiment TOML file.

    Raises
    ------
    ConfigError
        Missing file, invalid TOML, unknown section/key (naming it, the file and the allowed
        keys), missing scene file, per-frame list of the wrong length, or any invalid value.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"experiment file {path} does not exist")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read experiment file {path}: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: invalid TOML: {exc}") from exc
    return Experiment.from_dict(data, base_dir=path.parent, source=path)
