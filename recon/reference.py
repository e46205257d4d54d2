"""Reference volumes for the simulator self-calibration of the reconstruction's bias.

The reconstruction places a particle's centre with a fixed bias that depends on its depth and
on where it lies under its lenslet (its lenslet phase); noise, the detector and the localiser
add little to it. The simulator, which models the user's microscope, measures that bias where
the particles were found: for every frame, noise-free spheres are rendered through the ideal
lenslets of the reconstruction's model (:func:`lfsim.tracer.trace_paraxial`, ``mode =
"expected"``) at the detected positions, and the rendered image is reconstructed exactly as
the frame was (:func:`recon.pipeline.reconstruct_series`: same calibration, settings and
preprocessing). Localising each sphere in that reference volume at its own detected position
(``track.axial_bias``) gives the bias to subtract. Nothing is fitted to a truth.

``WORK/frames/NNNNNN.tif`` holds the rendered images (``frames.json`` the checksum of the
positions each was rendered from: a frame whose positions did not change is not rendered
again) and ``WORK/volumes/`` the reference volumes, which resume as any ``recon run`` does.
The rays are seeded; ``"expected"`` mode sums them with float atomics, so a re-render may
differ in the last bits (never re-rendered for unchanged positions).
"""

from __future__ import annotations

import hashlib
import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import InputError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ReferenceSettings:
    """How the reference images are rendered.

    Attributes
    ----------
    sphere_diameter_um : float
        Diameter of the rendered spheres (µm): the particles' (15 µm in the paper).
    rays_per_particle : int
        Rays per sphere (``mode = "expected"``: no shot noise; more rays, less ray noise).
    seed : int
        Seed of the rays.
    counts_per_ray : float
        Image counts per ray (sets the spheres' brightness against the black level).
    black_level : float
        Constant added to the image (the frames' preprocessing estimates and models it).
    """

    sphere_diameter_um: float = 15.0
    rays_per_particle: int = 50_000
    seed: int = 5
    counts_per_ray: float = 0.02
    black_level: float = 100.0

    def __post_init__(self) -> None:
        for name in ("sphere_diameter_um", "counts_per_ray"):
            v = getattr(self, name)
            if not isinstance(v, int | float) or isinstance(v, bool) or not v > 0:
                raise InputError(f"{name} must be a number > 0, got {v!r}")
        for name, least in (("rays_per_particle", 1), ("seed", 0)):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < least:
                raise InputError(f"{name} must be an integer >= {least}, got {v!r}")
        v = self.black_level
        if not isinstance(v, int | float) or isinstance(v, bool) or not v >= 0:
            raise InputError(f"black_level must be a number >= 0, got {v!r}")


def positions_checksum(positions_xyz_um: np.ndarray, settings: ReferenceSettings) -> str:
    """SHA-256 of the positions (float64, C order) and the render settings."""
    pos = np.ascontiguousarray(np.asarray(positions_xyz_um, dtype=np.float64).reshape(-1, 3))
    h = hashlib.sha256(pos.tobytes())
    h.update(repr(settings).encode())
    return h.hexdigest()


def render_reference(
    positions_xyz_um: np.ndarray, optics, settings: ReferenceSettings | None = None
) -> np.ndarray:
    """Noise-free image of spheres at ``positions_xyz_um`` through ideal lenslets.

    Parameters
    ----------
    positions_xyz_um : ndarray, shape (N, 3)
        Sphere centres (µm; x, y, z); N may be 0.
    optics : lfsim.optics.Optics
        The microscope of the reconstruction (glass lenslets are modelled as ideal ones,
        :func:`recon.pipeline.model_optics`).
    settings : ReferenceSettings, optional

    Returns
    -------
    ndarray, shape (height, width), float32
        Counts, ``black_level`` included.
    """
    from lfsim import init_backend
    from lfsim.backend import backend_info
    from lfsim.tracer import RenderSettings, Sources, trace_paraxial

    from .pipeline import model_optics

    st = settings or ReferenceSettings()
    pos = np.asarray(positions_xyz_um, dtype=np.float64)
    if pos.size == 0:
        pos = pos.reshape(0, 3)
    if pos.ndim != 2 or pos.shape[1] != 3 or not np.all(np.isfinite(pos)):
        raise InputError(f"positions must be a finite (N, 3) array (x, y, z µm), got {pos.shape}")
    ropt = model_optics(optics)
    h, w = ropt.sensor_xy_px[1], ropt.sensor_xy_px[0]
    if len(pos) == 0:
        return np.full((h, w), st.black_level, dtype=np.float32)
    if backend_info() is None:
        init_backend()
    # A detection at a specimen's surface: the specimen goes on, as in the bank's guard planes.
    img = trace_paraxial(
        ropt,
        Sources.spheres(pos, st.sphere_diameter_um),
        RenderSettings(rays_per_particle=st.rays_per_particle, mode="expected", seed=st.seed),
        virtual_front=True,
    )
    return (np.asarray(img, dtype=np.float64) * st.counts_per_ray + st.black_level).astype(
        np.float32
    )


def reference_preprocess():
    """How the rendered images are prepared: their constant black level is estimated (median)
    and modelled, as ``recon run`` does by default. The frames' own dark frame or hot-pixel
    filter does not apply to a noise-free rendering; whatever they used, the reference reaches
    the deconvolution with the same zero floor."""
    from .preprocess import Preprocess

    return Preprocess(background="auto")


def reference_volumes(
    positions_xyz_um,
    work_dir: str | os.PathLike,
    *,
    optics,
    grid,
    recon_settings=None,
    preprocess=None,
    settings: ReferenceSettings | None = None,
    progress: bool = False,
    parallel=None,
) -> list[Path]:
    """Render and reconstruct the reference of every frame (see the module docstring).

    Parameters
    ----------
    positions_xyz_um : sequence of ndarray, shape (N_k, 3)
        Particle positions of each frame (µm; x, y, z), e.g. the detections.
    work_dir : path
        ``frames/`` and ``volumes/`` go there; a previous run there is resumed (frames whose
        positions are unchanged are neither rendered nor reconstructed again).
    optics : lfsim.optics.Optics
        The reconstruction's scene (its lenslets are modelled as ideal ones).
    grid : recon.calibration.LensletGrid
        The calibration the frames were reconstructed with.
    recon_settings : ReconSettings, optional
    preprocess : Preprocess, optional
        Of the rendered images; default :func:`reference_preprocess`.
    settings : ReferenceSettings, optional
    progress : bool
    parallel : hrvbase.parallel.Parallel, optional
        Where the reconstructions run.

    Returns
    -------
    list of Path
        ``work_dir/volumes/NNNNNN.tif``, one per frame: same shape, voxel size and origin as
        the frames' volumes.
    """
    import tifffile

    from hrvbase.io import read_json, write_json

    from .pipeline import reconstruct_series

    st = settings or ReferenceSettings()
    work = Path(work_dir)
    frames_dir = work / "frames"
    frames_dir.mkdir(parents=True, exist_ok=True)
    record_path = frames_dir / "frames.json"
    record = read_json(record_path) if record_path.is_file() else {}
    paths = []
    for k, pos in enumerate(positions_xyz_um):
        path = frames_dir / f"{k:06d}.tif"
        sha = positions_checksum(pos, st)
        if record.get(str(k)) != sha or not path.is_file():
            img = render_reference(pos, optics, st)
            tmp = path.with_suffix(".tmp.tif")
            tifffile.imwrite(tmp, img)
            os.replace(tmp, path)
            record[str(k)] = sha
            write_json(record_path, record, overwrite=True)
        else:
            log.info("%s: positions unchanged, not rendered again", path)
        paths.append(path)
    res = reconstruct_series(
        paths,
        work / "volumes",
        optics=optics,
        grid=grid,
        settings=recon_settings,
        preprocess=preprocess or reference_preprocess(),
        overwrite=True,  # our own folder: replace only what these frames no longer make
        progress=progress,
        provenance={"reference": "simulated spheres at detected positions"},
        parallel=parallel,
    )
    return [res.out_dir / f"{k:06d}.tif" for k in range(len(paths))]


__all__ = [
    "ReferenceSettings",
    "positions_checksum",
    "reference_preprocess",
    "reference_volumes",
    "render_reference",
]
