"""Command-line interface ``lfsim``: scenes, single renders, calibration images, datasets.

::

    lfsim [--threads N] [--device {auto,llvm,cuda}] [-v] [-q] COMMAND ...

    lfsim scene --preset {paper_4x,small} [--mla {ideal,glass}] [--set KEY=VALUE ...]
                -o OUT.xml [--overwrite]
    lfsim render SCENE.xml --particles P.csv -o IMAGE.tif [--rays 100000]
                [--noise {none,gaussian,camera}] [--snr 17] [--bit-depth 8] [--seed 0]
                [--tracer {mitsuba,paraxial}] [--model {ray,wave}] [--no-diffraction]
                [--float] [--overwrite]
    lfsim white SCENE.xml -o WHITE.tif [--rays-per-lenslet 20000] [--snr 50] [--bit-depth 16]
                [--seed 0] [--overwrite]
    lfsim micrometer SCENE.xml -o M.tif [--division-um 10] [--axis {x,y}] [--snr 50]
                [--rotation-deg 0] [--z-um 0] [--bit-depth 16] [--seed 0] [--overwrite]
    lfsim dataset EXPERIMENT.toml -o DIR [--overwrite] [--workers N | --scheduler ADDRESS]

Lengths in µm. SNR is ``S / sigma_noise`` with ``S`` the 99.9th percentile of the noise-free
image (for sparse images, such as a single particle, half the 99.9th percentile of its lit
pixels when that is higher; ``docs/conventions.md``). Every error a user can cause prints one
line ``lfsim: error: ...`` and exits with status 2; outputs are written atomically and never
replace an existing file without ``--overwrite``.
"""

from __future__ import annotations

import argparse
import logging
import sys
from dataclasses import fields
from pathlib import Path

import numpy as np

from .errors import ConfigError

log = logging.getLogger("lfsim")

PRESETS = ("paper_4x", "small")


# -- helpers ----------------------------------------------------------------------------------
def _check_output(args, *inputs) -> Path:
    """Fail early (before any work) if ``args.output`` may not be written (see
    :func:`hrvbase.io.check_output_file`: never onto or into an input)."""
    from hrvbase.io import check_output_file

    return check_output_file(args.output, inputs=inputs, overwrite=args.overwrite)


def _check_numbers(args, rays: str) -> None:
    """Refuse, before any tracing, option values the library would refuse later (or only
    after tracing): rays, ``--snr``, ``--seed`` and the micrometer's lengths, named as typed."""
    from hrvbase.errors import raised_as
    from hrvbase.validate import int_in_range, positive_float

    with raised_as(ConfigError):
        int_in_range(getattr(args, rays.lstrip("-").replace("-", "_")), rays, 1)
        if args.snr is not None:
            positive_float(args.snr, "--snr")
        int_in_range(args.seed, "--seed", 0)
        if getattr(args, "division_um", None) is not None:
            positive_float(args.division_um, "--division-um")
            positive_float(args.line_width_um, "--line-width-um")


def _option_names(exc: ConfigError, names: dict[str, str]) -> ConfigError:
    """``exc`` with the library's parameter names replaced by the options the user typed."""
    from hrvbase.cli import rename_fields

    return ConfigError(rename_fields(str(exc), names))


def _parse_set(items: list[str]) -> dict:
    """``KEY=VALUE`` strings → Optics keyword arguments of the right types."""
    from hrvbase.validate import renamed_key_message

    from .optics import Optics

    types = {f.name: f.type for f in fields(Optics)}
    out: dict = {}
    for item in items:
        key, sep, value = item.partition("=")
        key, value = key.strip(), value.strip()
        if not sep or not key:
            raise ConfigError(f"--set expects KEY=VALUE, got {item!r}")
        renamed = renamed_key_message(key, types)
        if renamed is not None:
            raise ConfigError(f"--set: {renamed}")
        if key not in types:
            raise ConfigError(
                f"--set: unknown optics key {key!r}; allowed keys: {', '.join(sorted(types))}"
            )
        try:
            if key in ("sensor_xy_px", "axis_xy_px"):
                parts = value.replace("x", ",").replace("×", ",").split(",")
                conv = int if key == "sensor_xy_px" else float
                out[key] = tuple(conv(p) for p in parts if p.strip())
            elif key == "mla_kind":
                out[key] = value
            else:
                out[key] = float(value)
        except ValueError:
            raise ConfigError(f"--set {key}: cannot parse {value!r}") from None
    return out


def _read_scene(path: str):
    from .scene import load_scene

    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"scene file {p} does not exist")
    return load_scene(p)


def _check_tracer(args, scene) -> None:
    """Refuse ``--tracer paraxial`` on a scene whose lenslets it does not model."""
    kind = getattr(getattr(scene, "optics", scene), "mla_kind", "ideal")
    if args.tracer == "paraxial" and kind != "ideal":
        raise ConfigError(
            f"--tracer paraxial models ideal lenslets only, but scene {args.scene} has a "
            f"{kind!r} microlens array: use --tracer mitsuba (the default), or a scene with "
            "ideal lenslets (`lfsim scene --mla ideal`)"
        )


def _noise_seed(seed: int) -> np.random.Generator:
    # Independent of the tracer's stream for the same seed.
    return np.random.default_rng(np.random.SeedSequence([seed, 0x6E6F6973]))


def _base_meta(kind: str, scene, scene_path: str) -> dict:
    from . import __version__
    from .io import sha256_file

    return {
        "kind": kind,
        "lfsim_version": __version__,
        "scene": str(Path(scene_path).resolve()),
        "scene_sha256": sha256_file(scene_path),
        "pixel_size_um": scene.optics.object_pixel_um,
    }


# -- subcommands ----------------------------------------------------------------------------
def cmd_scene(args) -> int:
    from .optics import paper_optics, small_optics
    from .scene import write_scene

    out = _check_output(args)
    overrides = _parse_set(args.set or [])
    if args.mla is not None:
        if "mla_kind" in overrides and overrides["mla_kind"] != args.mla:
            raise ConfigError("--mla and --set mla_kind disagree")
        overrides["mla_kind"] = args.mla
    try:
        optics = (paper_optics if args.preset == "paper_4x" else small_optics)(**overrides)
    except TypeError as exc:  # pragma: no cover - keys are checked above
        raise ConfigError(str(exc)) from exc
    desc = f"preset {args.preset}, mla {optics.mla_kind}"
    if args.set:
        desc += ", " + ", ".join(args.set)
    # Write next to the destination, then move into place without clobbering.
    write_scene(optics, out, description=desc.replace("--", "- -"))
    x0, x1, y0, y1 = optics.field_of_view_xy_um
    log.info(
        "wrote %s: field x ∈ [%.1f, %.1f] µm, y ∈ [%.1f, %.1f] µm, %.4g µm/px",
        out,
        x0,
        x1,
        y0,
        y1,
        optics.object_pixel_um,
    )
    return 0


def _write_image(args, scene, img, meta) -> Path:
    """Write a rendered image with its metadata and object-space pixel size (atomic)."""
    from .io import write_tiff

    return write_tiff(
        Path(args.output),
        img,
        metadata=meta,
        pixel_size_um=scene.optics.object_pixel_um,
        overwrite=args.overwrite,
    )


def _write_noisy_slide(args, scene, clean, kind: str, **extra) -> Path:
    """White and micrometer images: Gaussian noise at ``--snr``, metadata, atomic write."""
    from .noise import add_gaussian_noise

    img, info = add_gaussian_noise(
        clean.astype(np.float64), args.snr, _noise_seed(args.seed), bit_depth=args.bit_depth
    )
    meta = _base_meta(kind, scene, args.scene)
    meta.update(**extra, seed=args.seed, noise=info)
    return _write_image(args, scene, img, meta)


def _warn_overlaps(particles, path, shown: int = 3) -> None:
    """One warning naming the rows (1-based data rows of the table) and positions of
    particles at the same place or overlapping (:meth:`lfsim.particles.Particles.overlaps`)."""
    coincident, overlapping = particles.overlaps()
    if not coincident and not overlapping:
        return
    pos, diam = particles.positions_um, particles.diameter_um

    def at(i: int) -> str:
        return "(" + ", ".join(f"{v:g}" for v in pos[i]) + ")"

    def rows(group) -> str:
        return ", ".join(str(i + 1) for i in group)

    parts = [f"rows {rows(g)} coincide at {at(g[0])} µm" for g in coincident[:shown]]
    parts += [
        f"rows {i + 1} and {j + 1} overlap, {d:.3g} µm apart at {at(i)} and {at(j)} µm "
        f"(diameters {diam[i]:g} and {diam[j]:g} µm)"
        for i, j, d in overlapping[:shown]
    ]
    more = max(len(coincident) - shown, 0) + max(len(overlapping) - shown, 0)
    tail = f"; and {more} more" if more else ""
    why = " (a row given twice renders one bead twice as bright)" if coincident else ""
    log.warning("particle table %s: %s%s; rendered as given%s", path, "; ".join(parts), tail, why)


def cmd_render(args) -> int:
    from .experiment import DEFAULT_NOISE
    from .io import sha256_file
    from .noise import NoiseSpec, apply_noise
    from .particles import Particles
    from .render import render_particles
    from .tracer import RenderSettings

    out = _check_output(args, args.scene, args.particles)
    _check_numbers(args, "--rays")
    particles = Particles.from_csv(args.particles)
    if len(particles) == 0:
        raise ConfigError(
            f"particle table {args.particles} holds no particles (a header only); expected one "
            "row per particle"
        )
    _warn_overlaps(particles, args.particles)
    if args.float and (args.snr is not None or args.bit_depth is not None or args.noise):
        raise ConfigError(
            "--float writes the noise-free image; it takes no --noise/--snr/--bit-depth"
        )
    noise_model = args.noise or "gaussian"
    if args.snr is not None and noise_model != "gaussian":
        raise ConfigError(f"--snr applies to --noise gaussian only, not {noise_model!r}")
    spec = None
    if not args.float:
        spec = NoiseSpec(
            model=noise_model,
            snr=(DEFAULT_NOISE["snr"] if args.snr is None else args.snr)
            if noise_model == "gaussian"
            else None,
            bit_depth=args.bit_depth,
        )
    scene = _read_scene(args.scene)
    _check_tracer(args, scene)
    settings = RenderSettings(
        rays_per_particle=args.rays,
        mode="expected" if args.float else "photons",
        diffraction=not args.no_diffraction,
        seed=args.seed,
        progress=not args.quiet,
        model=args.model,
    )
    clean = render_particles(scene, particles, settings, tracer=args.tracer)
    meta = _base_meta("light-field image", scene, args.scene)
    meta.update(
        particles=str(Path(args.particles).resolve()),
        particles_sha256=sha256_file(args.particles),
        n_particles=len(particles),
        rays_per_particle=args.rays,
        tracer=args.tracer,
        model=args.model,
        diffraction=not args.no_diffraction,
        seed=args.seed,
    )
    if args.float:
        img = clean.astype(np.float32)
        meta["units"] = "expected photons per pixel (noise-free)"
    else:
        img, info = apply_noise(clean, spec, _noise_seed(args.seed))
        meta["noise"] = info
    _write_image(args, scene, img, meta)
    log.info("wrote %s (%s, %d particles)", out, img.dtype, len(particles))
    return 0


def cmd_white(args) -> int:
    from .render import render_white

    out = _check_output(args, args.scene)
    _check_numbers(args, "--rays-per-lenslet")
    scene = _read_scene(args.scene)
    _check_tracer(args, scene)
    clean = render_white(
        scene, args.rays_per_lenslet, seed=args.seed, tracer=args.tracer, progress=not args.quiet
    )
    _write_noisy_slide(args, scene, clean, "white", rays_per_lenslet=args.rays_per_lenslet)
    log.info("wrote %s", out)
    return 0


def cmd_micrometer(args) -> int:
    from .render import micrometer_placement, micrometer_sources, render_micrometer

    out = _check_output(args, args.scene)
    _check_numbers(args, "--rays-per-line")
    scene = _read_scene(args.scene)
    try:  # the reticle fits the field and its slide (before tracing)
        slide, z_um = micrometer_placement(scene.optics, args.z_um)
        micrometer_sources(
            slide,
            args.division_um,
            args.line_width_um,
            args.axis,
            z_um=z_um,
            rotation_deg=args.rotation_deg,
        )
    except ConfigError as exc:
        raise _option_names(
            exc,
            {
                "division_um": "--division-um",
                "line_width_um": "--line-width-um",
                "rotation_deg": "--rotation-deg",
                "z_um": "--z-um",
            },
        ) from None
    # The slide as rendered, and as its metadata records it.
    slide = {
        "line_width_um": args.line_width_um,
        "axis": args.axis,
        "rays_per_line": args.rays_per_line,
        "rotation_deg": args.rotation_deg,
        "z_um": args.z_um,
    }
    clean = render_micrometer(scene, args.division_um, seed=args.seed, tracer=args.tracer, **slide)
    _write_noisy_slide(
        args, scene, clean, "stage micrometer", division_um=args.division_um, **slide
    )
    log.info("wrote %s (divisions every %g µm along %s)", out, args.division_um, args.axis)
    return 0


def cmd_dataset(args) -> int:
    from hrvbase.cli import parallel_from_args
    from hrvbase.io import check_output_folder, guard_output

    from .dataset import generate_dataset
    from .experiment import load_experiment

    parallel = parallel_from_args(args, threads=args.threads)
    exp = load_experiment(args.experiment)
    guard_output(args.output, [args.experiment, exp.scene])
    check_output_folder(args.output)
    generate_dataset(
        exp, args.output, overwrite=args.overwrite, progress=not args.quiet, parallel=parallel
    )
    return 0


# -- parser -----------------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    from hrvbase.cli import add_flags, add_parallel_options, tool_parser

    from . import __version__
    from .experiment import DEFAULT_NOISE, WhiteConfig
    from .render import (
        MICROMETER_DIVISION_UM,
        MICROMETER_LINE_WIDTH_UM,
        MICROMETER_RAYS_PER_LINE,
        WHITE_RAYS_PER_LENSLET,
    )
    from .tracer import RenderSettings

    p, sub, common = tool_parser(
        "lfsim",
        "Physically based light-field microscope simulator (lengths in µm).",
        f"lfsim (hrvptm) {__version__}",
        metavar="COMMAND",
        required=True,
    )
    p.add_argument(
        "--threads",
        type=int,
        default=None,
        help="CPU threads of the Dr.Jit backend (default: all cores)",
    )
    p.add_argument(
        "--device",
        choices=("auto", "llvm", "cuda"),
        default="auto",
        help="Dr.Jit backend (default: auto, CUDA if present, else LLVM)",
    )

    def value(q, flag: str, kind, default, text: str) -> None:
        q.add_argument(flag, type=kind, default=default, help=f"{text} (default {default:g})")

    def output(q, what: str, meta: str) -> None:
        q.add_argument("-o", "--output", required=True, metavar=meta, help=f"{what} (required)")
        add_flags(
            q, {"--overwrite": "replace an existing output file (never an input; default: refuse)"}
        )

    def image_options(q, *, snr: float | None, bits: int | None, what: str) -> None:
        q.add_argument("scene", metavar="SCENE.xml", help="scene file of the microscope")
        q.add_argument(
            "--snr",
            type=float,
            default=None if snr is None else snr,
            help="S/sigma of the Gaussian noise, S = P99.9 of the clean image "
            + f"(default {snr or DEFAULT_NOISE['snr']:g}"
            + ("" if snr else "; --noise gaussian only")
            + ")",
        )
        q.add_argument(
            "--bit-depth",
            type=int,
            choices=(8, 12, 16),
            default=bits,
            help=f"bits of the output pixels (default {bits or '8; camera model: its own 12'})",
        )
        q.add_argument(
            "--seed", type=int, default=0, help="seed of the rays and the noise (default 0)"
        )
        q.add_argument(
            "--tracer",
            choices=("mitsuba", "paraxial"),
            default="mitsuba",
            help="Mitsuba scene tracer or the direct paraxial one (default mitsuba)",
        )
        output(q, what, "OUT.tif")

    s = sub.add_parser(
        "scene", parents=[common], help="write a Mitsuba scene file of the microscope"
    )
    s.add_argument(
        "--preset",
        choices=PRESETS,
        required=True,
        help="paper_4x: Table 1 optics, 1280×800 px; small: 300×300 px (required)",
    )
    s.add_argument(
        "--mla",
        choices=("ideal", "glass"),
        default=None,
        help="ideal paraxial lenslets or a glass spherical-cap mesh (default ideal)",
    )
    s.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        help="override an Optics field in its unit (µm), e.g. na=0.3 or sensor_xy_px=640,400 "
        "(repeatable; default: none)",
    )
    output(s, "scene file to write", "OUT.xml")
    s.set_defaults(func=cmd_scene, needs_backend=False)

    r = sub.add_parser(
        "render", parents=[common], help="render particles from a CSV into a light-field image"
    )
    r.add_argument(
        "--particles",
        required=True,
        metavar="P.csv",
        help="CSV with x_um,y_um,z_um[,id,diameter_um,brightness] (required)",
    )
    value(r, "--rays", int, RenderSettings.rays_per_particle, "rays per particle")
    r.add_argument(
        "--noise",
        choices=("none", "gaussian", "camera"),
        default=None,
        help="noise model (default gaussian)",
    )
    r.add_argument(
        "--model",
        choices=("ray", "wave"),
        default="ray",
        help="optical model: ray tracing (--tracer) or scalar wave optics, ideal lenslets "
        "only, slower (default ray)",
    )
    add_flags(
        r,
        {
            "--no-diffraction": "no Gaussian diffraction blur (default: on)",
            "--float": "write the noise-free float32 expected-photon image instead (default: off)",
        },
    )
    image_options(r, snr=None, bits=None, what="light-field image to write")
    r.set_defaults(func=cmd_render, needs_backend=True)

    w = sub.add_parser(
        "white", parents=[common], help="flat-field image of a uniformly fluorescent slide"
    )
    value(w, "--rays-per-lenslet", int, WHITE_RAYS_PER_LENSLET, "rays traced per lenslet")
    image_options(w, snr=WhiteConfig.snr, bits=WhiteConfig.bit_depth, what="white image")
    w.set_defaults(func=cmd_white, needs_backend=True)

    m = sub.add_parser(
        "micrometer", parents=[common], help="stage-micrometer image for pixel-size calibration"
    )
    value(m, "--division-um", float, MICROMETER_DIVISION_UM, "line spacing in µm")
    value(m, "--line-width-um", float, MICROMETER_LINE_WIDTH_UM, "line width in µm")
    m.add_argument(
        "--axis",
        choices=("x", "y"),
        default="x",
        help="scale direction; x: lines perpendicular to x (default x)",
    )
    value(m, "--rays-per-line", int, MICROMETER_RAYS_PER_LINE, "rays traced per line")
    value(
        m,
        "--rotation-deg",
        float,
        0.0,
        "rotation of the reticle about the optical axis in degrees, from +x towards +y, "
        "in [-90, 90]",
    )
    value(
        m,
        "--z-um",
        float,
        0.0,
        "depth of the reticle in µm, i.e. its defocus (0: native object plane, in focus); "
        "in a scene with a specimen the reticle lies on the cover glass and this is its "
        "distance beyond the focus (>= 0)",
    )
    image_options(m, snr=WhiteConfig.snr, bits=WhiteConfig.bit_depth, what="micrometer image")
    m.set_defaults(func=cmd_micrometer, needs_backend=True)

    d = sub.add_parser(
        "dataset", parents=[common], help="generate (or resume) a dataset from an experiment TOML"
    )
    d.add_argument("experiment", metavar="EXPERIMENT.toml", help="experiment file (TOML)")
    d.add_argument("-o", "--output", required=True, metavar="DIR", help="dataset folder (required)")
    add_flags(
        d,
        {
            "--overwrite": "replace a dataset of another experiment (removes only lfsim's files; "
            "default: refuse)"
        },
    )
    add_parallel_options(d)
    d.set_defaults(func=cmd_dataset, needs_backend=True)
    return p


def _prepare(args) -> None:
    if args.threads is not None and args.threads < 1:
        raise ConfigError(f"--threads must be >= 1, got {args.threads}")
    if args.needs_backend:
        from .backend import init_backend

        init_backend(args.device, args.threads)


def main(argv: list[str] | None = None) -> int:
    """Run the ``lfsim`` command line; returns the exit status (0 ok, 2 error)."""
    from hrvbase.cli import run_main

    return run_main("lfsim", build_parser(), argv, loggers=("lfsim",), prepare=_prepare)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
