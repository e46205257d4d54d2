"""Light tracers: emit rays from fluorescent sources and count them on the sensor.

Two implementations of one optical model share the emission sampling and pixel binning:

- :func:`trace_mitsuba` propagates rays through a loaded Mitsuba scene with
  ``scene.ray_intersect`` and ``bsdf.sample`` (any optics a scene can hold: ideal or glass
  microlens arrays, apertures, extra lenses). Mitsuba's ``ptracer`` integrator cannot reach a
  film behind lenses, hence this tracer.
- :func:`trace_paraxial` writes the same ideal optics (thin lenses with slopes, stop, paraxial
  lenslet array — paper Eqs. 5–7) directly in Dr.Jit with no Mitsuba scene: the reference for
  tests and the fast path wherever only ideal optics are needed (PSF banks).

Emission (paper Eqs. 3–4). Each source emits isotropically; only rays inside the cone the
objective accepts can reach the sensor. With the aperture stop in the objective's back focal
plane that cone is the same for every point — half-angle ``asin(NA)`` about the optical axis —
so directions are drawn uniformly inside it and no ray is wasted; every ray therefore stands
for ``cone_fraction`` of the isotropic emission. Sphere sources (particles, 15 µm by default)
start rays uniformly inside their volume; box sources (a fluorescent slide, micrometer
divisions) uniformly inside their box.

Diffraction (paper §2.2). Ray positions receive an isotropic Gaussian offset where they cross
the microlens array and where they reach the sensor, of standard deviations
``Optics.sigma_mla_um = 0.21 λ / NA_image`` and ``Optics.sigma_sensor_um = 0.21 λ / NA_lenslet``
(Gaussian approximation of the Airy pattern of the objective and of one lenslet).

Determinism. Every ray draws its random numbers from its own PCG32 stream indexed by the
global ray number and the seed, and photon counts are accumulated as unsigned integers, so an
image depends only on the inputs and the seed — not on batch size or thread count.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from .errors import ConfigError

log = logging.getLogger(__name__)

MODES = ("photons", "expected")
#: Optical models of a particle image (:func:`lfsim.render.render_particles`).
MODELS = ("ray", "wave")

#: Axial step (mm) by which a ray leaves a specimen plane in the Mitsuba tracer (well above the
#: float32 spacing of scene coordinates 500 mm from the origin, 6e-5 mm).
INTERFACE_STEP_MM = 1e-3
UM_PER_MM = 1000.0


@dataclass(frozen=True)
class RenderSettings:
    """How to trace one image.

    Parameters
    ----------
    rays_per_particle : int
        Rays (photons inside the collection cone) per source of brightness 1. A source of
        brightness ``b`` emits ``round(b · rays_per_particle)`` rays in ``"photons"`` mode.
    mode : {"photons", "expected"}
        ``"photons"``: every ray is one photon, counts accumulate as ``uint32`` (bit-identical
        for a seed). ``"expected"``: every source emits exactly ``rays_per_particle`` rays of
        weight ``b``, accumulated as ``float32`` — the expected photon image for sources that
        emit ``b · rays_per_particle`` photons into the cone (float atomics: not bit-identical
        across thread counts).
    diffraction : bool
        Apply the Gaussian diffraction blur at the array and at the sensor.
    seed : int
    batch_rays : int
        Rays traced per kernel launch; bounds memory (about 50 bytes per ray).
    cone_margin : float
        Relative widening of the sampled cone half-angle (0 = exactly the accepted cone; tests
        use > 0 to check that the aperture stop clips the rest).
    progress : bool
        Show a progress bar over batches.
    model : {"ray", "wave"}
        Optical model of particle images (:func:`lfsim.render.render_particles`): ``"ray"``
        traces rays with the chosen tracer; ``"wave"`` sums scalar wave-optics light fields
        over each particle (:mod:`lfsim.wave_render`; ideal lenslets only), in the same
        photometric units (``rays_per_particle`` photons into the cone per unit brightness).
    """

    rays_per_particle: int = 100_000
    mode: str = "photons"
    diffraction: bool = True
    seed: int = 0
    batch_rays: int = 1 << 22
    cone_margin: float = 0.0
    progress: bool = False
    model: str = "ray"

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise ConfigError(f"model must be one of {MODELS}, got {self.model!r}")
        if int(self.rays_per_particle) != self.rays_per_particle or self.rays_per_particle < 1:
            raise ConfigError(
                f"rays_per_particle must be a positive integer, got {self.rays_per_particle!r}"
            )
        if self.mode not in MODES:
            raise ConfigError(f"mode must be one of {MODES}, got {self.mode!r}")
        if int(self.seed) != self.seed or self.seed < 0:
            raise ConfigError(f"seed must be a non-negative integer, got {self.seed!r}")
        if self.batch_rays < 1024:
            raise ConfigError(f"batch_rays must be >= 1024, got {self.batch_rays!r}")
        if not (0.0 <= self.cone_margin < 1.0):
            raise ConfigError(f"cone_margin must lie in [0, 1), got {self.cone_margin!r}")


@dataclass(frozen=True)
class Sources:
    """Emitters of one image, in object space (µm).

    ``kind="sphere"``: ``centers_um`` (N, 3), ``sizes_um`` (N,) diameters.
    ``kind="box"``: ``centers_um`` (N, 3) box centres, ``sizes_um`` (N, 3) box edge lengths.
    ``weights`` (N,) relative brightness (≥ 0).
    """

    kind: str
    centers_um: np.ndarray
    sizes_um: np.ndarray
    weights: np.ndarray

    @classmethod
    def spheres(cls, centers_um, diameters_um, weights=None) -> Sources:
        c = np.asarray(centers_um, dtype=np.float64).reshape(-1, 3)
        d = np.broadcast_to(np.asarray(diameters_um, dtype=np.float64), (len(c),)).copy()
        w = np.ones(len(c)) if weights is None else np.asarray(weights, dtype=np.float64)
        return cls("sphere", c, d, w)

    @classmethod
    def boxes(cls, centers_um, sizes_um, weights=None) -> Sources:
        c = np.asarray(centers_um, dtype=np.float64).reshape(-1, 3)
        s = np.broadcast_to(np.asarray(sizes_um, dtype=np.float64), (len(c), 3)).copy()
        w = np.ones(len(c)) if weights is None else np.asarray(weights, dtype=np.float64)
        return cls("box", c, s, w)

    def __post_init__(self) -> None:
        if self.kind not in ("sphere", "box"):
            raise ConfigError(f"source kind must be 'sphere' or 'box', got {self.kind!r}")
        if not np.all(np.isfinite(self.centers_um)):
            raise ConfigError("source positions must be finite (found NaN or inf)")
        if np.any(self.sizes_um < 0) or not np.all(np.isfinite(self.sizes_um)):
            raise ConfigError("source sizes must be finite and non-negative")
        if np.any(self.weights < 0) or not np.all(np.isfinite(self.weights)):
            raise ConfigError("source brightness must be finite and non-negative")

    def __len__(self) -> int:
        return len(self.centers_um)


def _ray_counts(sources: Sources, settings: RenderSettings) -> np.ndarray:
    n = settings.rays_per_particle
    if settings.mode == "photons":
        return np.rint(sources.weights * n).astype(np.int64)
    return np.where(sources.weights > 0, n, 0).astype(np.int64)


def _seed_words(seed: int) -> tuple[int, int]:
    # SplitMix64 of the seed: decorrelates nearby seeds' PCG32 streams.
    def mix(z):
        z = (z + 0x9E3779B97F4A7C15) & 0xFFFFFFFFFFFFFFFF
        z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & 0xFFFFFFFFFFFFFFFF
        z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & 0xFFFFFFFFFFFFFFFF
        return z ^ (z >> 31)

    a = mix(int(seed))  # a Python int: numpy integers would overflow in the mixing
    return a, mix(a)


def _check_inside_specimen(sources: Sources, optics) -> None:
    """Every source lies wholly beyond the specimen's near surface (where there is one)."""
    if not optics.has_interfaces or len(sources) == 0:
        return
    half = sources.sizes_um / 2 if sources.kind == "sphere" else sources.sizes_um[:, 2] / 2
    near = sources.centers_um[:, 2] - half
    bad = np.flatnonzero(near < optics.surface_z_um - 1e-6)
    if len(bad):
        k = int(bad[0])
        raise ConfigError(
            f"{len(bad)} source(s) reach in front of the specimen's near surface at "
            f"z = {optics.surface_z_um:.4g} µm (first: #{k} at z = "
            f"{sources.centers_um[k, 2]:.4g} µm); move them deeper or raise focus_depth_um"
        )


class _Emitter:
    """Samples ray origins (µm, object frame) and unit directions for a batch of rays."""

    def __init__(
        self,
        sources: Sources,
        counts: np.ndarray,
        optics,
        settings: RenderSettings,
        virtual_front: bool = False,
    ):
        import drjit as dr
        import mitsuba as mi

        self.dr, self.mi = dr, mi
        self.kind = sources.kind
        self.offsets = np.concatenate([[0], np.cumsum(counts)])
        self.total = int(self.offsets[-1])
        if self.total >= 2**32:
            raise ConfigError(f"{self.total} rays in one image exceed 2**32; trace fewer rays")
        self.n_sources = len(counts)
        self.offsets_dr = mi.UInt32(self.offsets[:-1].astype(np.uint32))
        self.cx = mi.Float(sources.centers_um[:, 0].astype(np.float32))
        self.cy = mi.Float(sources.centers_um[:, 1].astype(np.float32))
        self.cz = mi.Float(sources.centers_um[:, 2].astype(np.float32))
        if self.kind == "sphere":
            self.size = [mi.Float((sources.sizes_um / 2).astype(np.float32))]
        else:
            self.size = [mi.Float(sources.sizes_um[:, k].astype(np.float32)) for k in range(3)]
        if not virtual_front:
            _check_inside_specimen(sources, optics)
        w = sources.weights if settings.mode == "expected" else np.ones(len(sources))
        self.weight = mi.Float(w.astype(np.float32))
        theta = min(optics.emission_half_angle * (1.0 + settings.cone_margin), math.pi / 2)
        self.cos_cutoff = math.cos(theta)
        self.seed = _seed_words(settings.seed)

    def batch(self, start: int, n: int):
        dr, mi = self.dr, self.mi
        ray_id = mi.UInt32(start) + dr.arange(mi.UInt32, n)
        offsets = self.offsets_dr
        # Source of each ray: the last source whose first ray index is <= ray_id.
        src = (
            dr.binary_search(
                0, self.n_sources, lambda i: dr.gather(mi.UInt32, offsets, i) <= ray_id
            )
            - 1
        )
        rng = mi.PCG32(
            size=n,
            initstate=mi.UInt64(self.seed[0]) + start,
            initseq=mi.UInt64(self.seed[1]) + start,
        )
        c = mi.Point3f(
            dr.gather(mi.Float, self.cx, src),
            dr.gather(mi.Float, self.cy, src),
            dr.gather(mi.Float, self.cz, src),
        )
        u1, u2, u3 = rng.next_float32(), rng.next_float32(), rng.next_float32()
        if self.kind == "sphere":
            r = dr.gather(mi.Float, self.size[0], src) * dr.cbrt(u3)
            o = c + mi.warp.square_to_uniform_sphere(mi.Point2f(u1, u2)) * r
        else:
            sx, sy, sz = (dr.gather(mi.Float, s, src) for s in self.size)
            o = c + mi.Vector3f((u1 - 0.5) * sx, (u2 - 0.5) * sy, (u3 - 0.5) * sz)
        d = mi.warp.square_to_uniform_cone(
            mi.Point2f(rng.next_float32(), rng.next_float32()), self.cos_cutoff
        )
        w = dr.gather(mi.Float, self.weight, src)
        return rng, o, d, w, src


def _specimen_layers(optics) -> list[tuple[float, float, float]]:
    """Planar interfaces from the specimen to the immersion medium, in the order light meets
    them: ``(travel_um, n_from, n_to)``, ``travel_um`` being the axial path in the layer
    *before* the interface (0 for the specimen itself, whose path depends on the source)."""
    layers = []
    n = optics.medium_ior
    if optics.coverslip_thickness_um > 0:
        layers.append((0.0, n, optics.coverslip_ior))
        layers.append((optics.coverslip_thickness_um, optics.coverslip_ior, optics.immersion_ior))
    elif n != optics.immersion_ior:
        layers.append((0.0, n, optics.immersion_ior))
    return layers


def _fresnel_transmittance(dr, mi, cos_i, n_from: float, n_to: float):
    """Unpolarised Fresnel transmittance of a planar interface (Mitsuba's ``fresnel``)."""
    f, _cos_t, _eta_it, _eta_ti = mi.fresnel(cos_i, mi.Float(n_to / n_from))
    return 1.0 - f


def to_immersion(optics, o, d, dr, mi, *, virtual_front: bool = False):
    """Carry rays from the specimen through its planar interfaces into the immersion medium.

    Exact Snell refraction at every interface (the transverse direction cosines scale by
    ``n_from / n_to``), total internal reflection dropped, and the cover glass the objective is
    corrected for (``coverslip_corrected_um`` of index ``coverslip_ior``) undone exactly: the
    ray is displaced laterally by ``t₀ (u_imm − u_glass)``, the difference a slab of that glass
    would have made, so the objective sees the ray it was designed for.

    Parameters
    ----------
    o : mitsuba.Point3f
        Ray origins, object frame (µm; ``z`` true distance in the specimen from the native
        object plane, growing away from the objective).
    d : mitsuba.Vector3f
        Unit directions in the specimen, ``d.z > 0`` towards the objective.
    virtual_front : bool
        Trace a source in front of the specimen's near surface as if the specimen went on
        towards the objective (a guard plane of a reconstruction volume, where nothing emits
        but the volume needs a model); otherwise its rays are dropped.

    Returns
    -------
    x, y, z : mitsuba.Float
        A point of the ray in the immersion medium, in the nominal frame (µm; ``z`` from the
        nominal focal plane, growing away from the objective).
    u, v : mitsuba.Float
        Slopes ``dx/dz``, ``dy/dz`` in the immersion medium, per unit of axial travel.
    transmittance : mitsuba.Float
        Product of the interfaces' Fresnel transmittances (0 for totally reflected rays).
    """
    if not optics.has_interfaces:
        return o.x, o.y, o.z, d.x / d.z, d.y / d.z, mi.Float(1.0)
    z = o.z + optics.focal_shift_um  # nominal frame
    z_surface = -optics.focus_depth_um
    # a virtual source is carried back along its ray to the surface, as if the specimen went on
    inside = z >= (-math.inf if virtual_front else z_surface)
    x, y = o.x + d.x / d.z * (z - z_surface), o.y + d.y / d.z * (z - z_surface)
    z = mi.Float(z_surface)
    dx, dy, dz = d.x, d.y, d.z
    trans = dr.select(inside, mi.Float(1.0), 0.0)
    for travel, n_from, n_to in _specimen_layers(optics):
        if travel > 0:
            x, y, z = x + dx / dz * travel, y + dy / dz * travel, z - travel
        trans *= _fresnel_transmittance(dr, mi, dz, n_from, n_to)
        a = n_from / n_to
        dx, dy = dx * a, dy * a
        sin2 = dx * dx + dy * dy
        trans = dr.select(sin2 < 1.0, trans, 0.0)
        dz = dr.sqrt(dr.maximum(1.0 - sin2, 1e-12))
    t0 = optics.coverslip_corrected_um
    if t0 > 0:
        a = optics.immersion_ior / optics.coverslip_ior
        gx, gy = dx * a, dy * a
        gz = dr.sqrt(dr.maximum(1.0 - (gx * gx + gy * gy), 1e-12))
        x = x + t0 * (dx / dz - gx / gz)
        y = y + t0 * (dy / dz - gy / gz)
    return x, y, z, dx / dz, dy / dz, trans


def objective_rays(optics, o, d, dr, mi, *, virtual_front: bool = False):
    """The rays the objective images: :func:`to_immersion`'s, and for an immersion objective
    (``Optics.is_immersion``) each one's air-equivalent ray.

    The air-equivalent ray passes through the ray's intercept with the nominal focal plane
    with slopes ``n_imm · (α, β)``, the direction sines of the ray in the immersion medium
    times its index: imaged by the objective's thin lens it crosses the back focal plane at
    ``f_obj · n_imm · sin θ`` (the sine condition) and leaves with the slope its intercept
    gives, so that the objective is aplanatic and a depth ``z`` in the immersion medium is
    imaged as ``z / n_imm`` would be in air (longitudinal magnification ``M² / n_imm``).

    Returns
    -------
    x, y, z, u, v, transmittance
        As :func:`to_immersion`; for an immersion objective the point is the intercept with
        the nominal focal plane (``z = 0``).
    """
    x, y, z, u, v, trans = to_immersion(optics, o, d, dr, mi, virtual_front=virtual_front)
    if not optics.is_immersion:
        return x, y, z, u, v, trans
    n = optics.immersion_ior
    scale = n * dr.rsqrt(1.0 + u * u + v * v)  # n / sec θ: slopes to n sin θ
    return x + u * z, y + v * z, dr.zeros(mi.Float, dr.width(x)), u * scale, v * scale, trans


class _Film:
    """Bins sensor positions (µm, sensor plane, scene axes) into pixels.

    With ``layers`` set, every source gets its own image (``layer`` index per ray).
    """

    def __init__(self, optics, settings: RenderSettings, layers: int | None = None):
        import drjit as dr
        import mitsuba as mi

        self.dr, self.mi = dr, mi
        self.w, self.h = optics.sensor_xy_px
        self.ax, self.ay = optics.axis_xy_px
        self.pix = optics.pixel_um
        self.photons = settings.mode == "photons"
        dtype = mi.UInt32 if self.photons else mi.Float
        self.layers = layers
        self.data = dr.zeros(dtype, self.w * self.h * (layers or 1))

    def splat(self, x_um, y_um, weight, active, layer=None):
        dr, mi = self.dr, self.mi
        col = mi.Int32(dr.floor(self.ax - x_um / self.pix))
        row = mi.Int32(dr.floor(self.ay - y_um / self.pix))
        ok = active & (col >= 0) & (col < self.w) & (row >= 0) & (row < self.h)
        index = mi.UInt32(dr.select(ok, row * self.w + col, 0))
        if layer is not None:
            index += layer * (self.w * self.h)
        value = mi.UInt32(1) if self.photons else weight
        dr.scatter_reduce(dr.ReduceOp.Add, self.data, value, index, ok)

    def numpy(self) -> np.ndarray:
        self.dr.eval(self.data)
        shape = (self.h, self.w) if self.layers is None else (self.layers, self.h, self.w)
        return self.data.numpy().reshape(shape)


def _gauss2(rng, dr, mi):
    g = mi.warp.square_to_std_normal(mi.Point2f(rng.next_float32(), rng.next_float32()))
    return g.x, g.y


def _batches(total: int, settings: RenderSettings, what: str):
    starts = range(0, total, settings.batch_rays)
    if settings.progress and len(starts) > 1:
        from tqdm.auto import tqdm

        return tqdm(starts, desc=what, unit="batch", leave=False)
    return starts


def _propagate(scene, film, ray, rng, w, sensor_blur, blur_mla, max_bounces, alive=None) -> None:
    """Symbolic loop: intersect, bin sensor hits, blur at the array, sample the BSDF
    (``alive``: the rays that start, default all)."""
    import drjit as dr
    import mitsuba as mi

    mi_scene = scene.mi_scene
    sensor_ptr = mi.ShapePtr(scene.sensor)
    mla_ptr = mi.ShapePtr(scene.mla)
    interfaces = [mi.ShapePtr(sh) for sh in scene.interfaces]
    gx, gy, s_sen = sensor_blur
    correction = None
    if scene.correction is not None:
        t0 = scene.optics.coverslip_corrected_um / UM_PER_MM
        a = scene.optics.immersion_ior / scene.optics.coverslip_ior

        def shift(d):  # t₀ (u_imm − u_glass), the cover glass the objective expects, undone
            gx_, gy_ = d.x * a, d.y * a
            gz_ = dr.sqrt(dr.maximum(1.0 - (gx_ * gx_ + gy_ * gy_), 1e-12))
            return mi.Vector3f(t0 * (d.x / d.z - gx_ / gz_), t0 * (d.y / d.z - gy_ / gz_), 0.0)

        correction = (mi.ShapePtr(scene.correction), shift)
    ctx = mi.BSDFContext()

    def cond(ray, active, depth, rng):
        return active

    def body(ray, active, depth, rng):
        si = mi_scene.ray_intersect(ray, active)
        active &= si.is_valid()
        on_sensor = active & (si.shape == sensor_ptr)
        x_um = si.p.x * UM_PER_MM + gx * s_sen
        y_um = si.p.y * UM_PER_MM + gy * s_sen
        film.splat(x_um, y_um, w, on_sensor)
        active &= ~on_sensor
        si.p = dr.select(active & (si.shape == mla_ptr), si.p + blur_mla, si.p)
        if correction is not None:
            si.p = dr.select(
                active & (si.shape == correction[0]), si.p + correction[1](ray.d), si.p
            )
        bsdf = si.bsdf(ray)
        bs, weight = bsdf.sample(ctx, si, rng.next_float32(active), mi.Point2f(0.5), active)
        depth += 1
        active &= (weight[0] > 0.0) & (depth < max_bounces)
        wo = si.to_world(bs.wo)
        ray = mi.Ray3f(si.spawn_ray(wo))
        if interfaces:
            # Mitsuba offsets a spawned ray along the normal by ~1e-4 of the distance to the
            # origin (45 µm at the specimen, 500 mm away): a lateral error of slope × 45 µm.
            # From the specimen's planes, step along the ray itself instead.
            on_plane = mi.Bool(False)
            for ptr in interfaces:
                on_plane |= si.shape == ptr
            step = INTERFACE_STEP_MM / dr.maximum(dr.abs(wo.z), 1e-3)
            ray.o = dr.select(active & on_plane, si.p + wo * step, ray.o)
        return ray, active, depth, rng

    dr.while_loop(
        (ray, mi.Bool(True) if alive is None else alive, mi.UInt32(0), rng),
        cond,
        body,
        labels=("ray", "active", "depth", "rng"),
    )


def trace_mitsuba(scene, sources: Sources, settings: RenderSettings) -> np.ndarray:
    """Trace ``sources`` through a loaded :class:`~lfsim.scene.LightFieldScene`.

    Returns
    -------
    ndarray, shape (height, width)
        ``uint32`` photon counts (mode ``"photons"``) or ``float32`` expected photons.
    """
    import drjit as dr
    import mitsuba as mi

    optics = scene.optics
    counts = _ray_counts(sources, settings)
    emitter = _Emitter(sources, counts, optics, settings)
    film = _Film(optics, settings)
    if emitter.total == 0:
        return film.numpy()
    lay = scene.layout
    s_mla = optics.sigma_mla_um / UM_PER_MM if settings.diffraction else 0.0
    s_sen = optics.sigma_sensor_um if settings.diffraction else 0.0
    max_bounces = (6 if optics.mla_kind == "ideal" else 12) + 3 * optics.has_interfaces
    for start in _batches(emitter.total, settings, "tracing"):
        n = min(settings.batch_rays, emitter.total - start)
        rng, o, d, w, _src = emitter.batch(start, n)
        if optics.is_immersion:
            # The air-equivalent rays (objective_rays), from the nominal focal plane; the
            # specimen's interfaces are not in the scene (lfsim.scene.write_scene).
            x, y, _z, u, v, trans = objective_rays(optics, o, d, dr, mi)
            nominal_z = lay.object_z + optics.focal_shift_um / UM_PER_MM
            origin = mi.Point3f(x / UM_PER_MM, y / UM_PER_MM, nominal_z)
            ray = mi.Ray3f(origin, dr.normalize(mi.Vector3f(u, v, 1.0)))
        else:
            origin = mi.Point3f(o.x / UM_PER_MM, o.y / UM_PER_MM, lay.object_z - o.z / UM_PER_MM)
            ray = mi.Ray3f(origin, mi.Vector3f(d.x, d.y, d.z))
        # Diffraction offsets drawn up front, in the same order as trace_paraxial.
        if settings.diffraction:
            gx, gy = _gauss2(rng, dr, mi)
            hx, hy = _gauss2(rng, dr, mi)
            blur_mla = mi.Vector3f(hx * s_mla, hy * s_mla, 0.0)
        else:
            gx = gy = mi.Float(0.0)
            blur_mla = mi.Vector3f(0.0)
        alive = None
        if optics.is_immersion and optics.has_interfaces:
            # Fresnel losses of the interfaces objective_rays crossed, drawn where
            # trace_paraxial draws them: a weight, or a photon's survival
            if settings.mode == "expected":
                w = w * trans
            else:
                alive = rng.next_float32() < trans

        _propagate(scene, film, ray, rng, w, (gx, gy, s_sen), blur_mla, max_bounces, alive)
        dr.eval(film.data)
    return film.numpy()


def trace_paraxial(
    optics,
    sources: Sources,
    settings: RenderSettings,
    *,
    per_source: bool = False,
    virtual_front: bool = False,
) -> np.ndarray:
    """Trace ``sources`` through ideal optics written directly in Dr.Jit (no Mitsuba).

    The same optics as an ``mla_kind="ideal"`` scene: objective and tube lens as thin lenses
    acting on slopes, the circular stop in their shared focal plane, the paraxial lenslet
    array (paper Eq. 7) and the sensor one lenslet focal length behind it; clear radii as in
    :func:`lfsim.scene.write_scene`. Random numbers are drawn in the same order as
    :func:`trace_mitsuba`, so both tracers see the same rays.

    Parameters
    ----------
    per_source : bool
        Give every source its own image (PSF banks): the result is ``(n_sources, h, w)``.
    virtual_front : bool
        Sources in front of the specimen's near surface are traced as if the specimen went on
        (:func:`to_immersion`; the guard planes of a PSF bank) instead of being refused.

    Returns
    -------
    ndarray, shape (height, width) or (n_sources, height, width)
    """
    import drjit as dr
    import mitsuba as mi

    from .scene import _radii_mm

    if optics.mla_kind != "ideal":
        raise ConfigError("trace_paraxial models ideal lenslets only (mla_kind='ideal')")
    counts = _ray_counts(sources, settings)
    emitter = _Emitter(sources, counts, optics, settings, virtual_front)
    film = _Film(optics, settings, layers=len(sources) if per_source else None)
    if emitter.total == 0:
        return film.numpy()
    fo, ft = optics.f_objective_um, optics.f_tube_um
    fl, p = optics.mla_focal_um, optics.mla_pitch_um
    r_obj, r_tube = (r * UM_PER_MM for r in _radii_mm(optics))
    r_stop = optics.stop_radius_um
    s_mla = optics.sigma_mla_um if settings.diffraction else 0.0
    s_sen = optics.sigma_sensor_um if settings.diffraction else 0.0
    for start in _batches(emitter.total, settings, "tracing"):
        n = min(settings.batch_rays, emitter.total - start)
        rng, o, d, w, src = emitter.batch(start, n)
        x, y, z, u, v, trans = objective_rays(optics, o, d, dr, mi, virtual_front=virtual_front)
        # Object point -> objective (distance f_obj + z: z grows away from the objective).
        t = fo + z
        x, y = x + u * t, y + v * t
        ok = x * x + y * y <= r_obj * r_obj
        u, v = u - x / fo, v - y / fo
        x, y = x + u * fo, y + v * fo  # aperture stop
        ok &= x * x + y * y <= r_stop * r_stop
        x, y = x + u * ft, y + v * ft  # tube lens
        ok &= x * x + y * y <= r_tube * r_tube
        u, v = u - x / ft, v - y / ft
        x, y = x + u * ft, y + v * ft  # microlens array
        if settings.diffraction:
            gx, gy = _gauss2(rng, dr, mi)
            hx, hy = _gauss2(rng, dr, mi)
            x, y = x + hx * s_mla, y + hy * s_mla
        if optics.has_interfaces:  # Fresnel losses: a weight, or a photon's survival
            if settings.mode == "expected":
                w = w * trans
            else:
                ok &= rng.next_float32() < trans
        sx, sy = p * dr.round(x / p), p * dr.round(y / p)
        u, v = u - (x - sx) / fl, v - (y - sy) / fl
        x, y = x + u * fl, y + v * fl  # sensor
        if settings.diffraction:
            x, y = x + gx * s_sen, y + gy * s_sen
        film.splat(x, y, w, ok, src if per_source else None)
        dr.eval(film.data)
    return film.numpy()
