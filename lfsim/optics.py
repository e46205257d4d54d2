"""The light-field microscope's optics as one typed, validated object.

:class:`Optics` is the single description of the optical train shared by the simulator
(:mod:`lfsim`) and the reconstruction (:mod:`recon`): it is written into and read back from
the Mitsuba scene files in ``scenes/`` (:mod:`lfsim.scene`), so both use exactly the same
numbers.

Model (paper §2.2, Table 1; docs/conventions.md §2). An infinity-corrected objective of focal length
``f_objective_um`` and a tube lens ``f_tube_um`` form a 4f system of lateral magnification
``M = f_tube / f_objective``; the aperture stop sits in the shared focal plane, so the system is
telecentric on both sides and the stop radius ``f_objective · tan(asin NA)`` fixes the
object-side numerical aperture. A square microlens array of pitch ``mla_pitch_um`` and focal
length ``mla_focal_um`` sits in the native image plane; the sensor lies one lenslet focal length
behind it (a relay lens between array and camera is folded into ``pixel_um``, the pixel size
referred to that plane). The image through the 4f system is inverted; the sensor's pixel grid
is read out so that object +x runs along increasing columns and +y along increasing rows.

The specimen (docs/conventions.md §2). The objective is designed for an immersion medium of
index ``immersion_ior`` (1 for a dry objective) and, optionally, for a cover glass of
thickness ``coverslip_corrected_um``; the thin-lens model above holds in that medium (ray slopes
are taken in the immersion medium). Between the objective and the particles lie, in order, the
immersion medium, an optional cover glass (or dish bottom) of thickness
``coverslip_thickness_um`` and index ``coverslip_ior``, and the specimen of index
``medium_ior``, which fills the half-space beyond the cover glass. ``focus_depth_um`` is the
user's focus setting: how far the stage moved the nominal focal plane into the specimen past
its near surface. Rays refract exactly (Snell's law) at the planar interfaces; a cover glass the
objective is corrected for is compensated exactly. The native object plane then lies
:attr:`Optics.focal_shift_um` beyond the nominal focal plane, and object coordinates ``z`` are
true distances in the specimen from it. The native plane may lie in front of the specimen (a
negative focus, in the cover glass or the immersion medium, keeps the whole specimen on one
side of it, away from the reconstruction's native-plane artefacts); ``z`` then continues the
specimen's depth scale through it, and the specimen's near surface lies at
``z = surface_z_um > 0``.

All lengths are micrometres.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from functools import cached_property

from .errors import ConfigError

MLA_KINDS = ("ideal", "glass")

#: The instrument's fields, which have no default.
REQUIRED = (
    "na",
    "f_objective_um",
    "f_tube_um",
    "mla_pitch_um",
    "mla_focal_um",
    "pixel_um",
    "sensor_xy_px",
)


def _positive(name: str, value: float) -> None:
    if not isinstance(value, int | float) or not math.isfinite(value) or value <= 0:
        raise ConfigError(f"{name} must be a positive finite number, got {value!r}")


#: Names under which the fingerprints and cache keys hash the fields named otherwise in the
#: API (docs/conventions.md §3), which are also the names of the files of the older layout:
#: a field's name does not change what the optics image.
FINGERPRINT_KEYS = {"sensor_xy_px": "sensor_px", "axis_xy_px": "axis_px"}
#: The older names → the fields' (:meth:`Optics.from_dict`).
OLDER_KEYS = {v: k for k, v in FINGERPRINT_KEYS.items()}

#: Largest sensor (pixels) the tracers can index: Dr.Jit arrays hold at most 2³² entries and
#: the film keeps several arrays of the sensor's size.
MAX_SENSOR_PIXELS = 1 << 28

#: The paper's microscope (Table 1): 4×/0.2 NA, 100 µm / f 1000 µm lenslets, 1280 × 800 px,
#: 15 px per lenslet. Only :func:`paper_optics` and the shipped paper scenes use it.
PAPER_OPTICS = {
    "na": 0.2,
    "f_objective_um": 50_000.0,
    "f_tube_um": 200_000.0,
    "mla_pitch_um": 100.0,
    "mla_focal_um": 1000.0,
    "pixel_um": 100.0 / 15.0,
    "sensor_xy_px": (1280, 800),
}


@dataclass(frozen=True, kw_only=True)
class Optics:
    """Optical parameters of a light-field microscope (all lengths in µm).

    There is no built-in microscope: the instrument's numbers (``na``, the focal lengths, the
    lenslet pitch and focal length, the pixel size and the sensor size) must all be given;
    :func:`paper_optics` gives the paper's.

    Parameters
    ----------
    na : float
        Object-side numerical aperture of the objective (0 < NA < 1).
    f_objective_um, f_tube_um : float
        Focal lengths of the objective and the tube lens; ``M = f_tube_um / f_objective_um``.
    mla_pitch_um, mla_focal_um : float
        Lenslet pitch and focal length of the square microlens array.
    pixel_um : float
        Sensor pixel size referred to the lenslets' back focal plane.
    sensor_xy_px : tuple of int
        Sensor size ``(width, height)`` in pixels.
    wavelength_um : float
        Emission wavelength (used by the diffraction blur).
    mla_kind : {"ideal", "glass"}
        Paraxial lenslet plane (paper Eq. 7) or a glass mesh of spherical-cap lenslets.
    mla_ior : float
        Refractive index of the glass array (``mla_kind="glass"``).
    mla_thickness_um : float
        Glass array thickness from the lenslet vertices to the flat back.
    medium_ior : float
        Refractive index of the specimen (1.0 air, 1.33 water, ≈ 1.35 a 10 % polyacrylamide
        gel, 1.41 PDMS).
    immersion_ior : float
        Index of the medium the objective is designed for (1.0 dry, 1.333 water, 1.518 oil);
        ``na`` must stay below it.
    coverslip_thickness_um : float
        Thickness of the cover glass or dish bottom between the immersion medium and the
        specimen (0: none).
    coverslip_ior : float
        Refractive index of the cover glass.
    coverslip_corrected_um : float
        Cover-glass thickness (of index ``coverslip_ior``) the objective is corrected for
        (0: not corrected, as most low-magnification dry objectives).
    focus_depth_um : float
        Focus setting: distance by which the stage moved the nominal focal plane into the
        specimen past its near surface (the cover glass's far face); negative when the
        nominal focal plane lies in front of the specimen. Used only where the specimen has an
        interface (:attr:`has_interfaces`).
    axis_xy_px : tuple of float, optional
        Sensor position ``(column, row)`` of the optical axis in continuous pixel coordinates
        (pixel ``i`` spans ``[i, i + 1)``). Default: the centre of the lenslet nearest to the
        sensor centre, so that lenslet borders fall on pixel borders when the pitch is an
        integer number of pixels.
    """

    na: float
    f_objective_um: float
    f_tube_um: float
    mla_pitch_um: float
    mla_focal_um: float
    pixel_um: float
    sensor_xy_px: tuple[int, int]
    wavelength_um: float = 0.605
    mla_kind: str = "ideal"
    mla_ior: float = 1.5
    mla_thickness_um: float = 300.0
    medium_ior: float = 1.0
    immersion_ior: float = 1.0
    coverslip_thickness_um: float = 0.0
    coverslip_ior: float = 1.523
    coverslip_corrected_um: float = 0.0
    focus_depth_um: float = 0.0
    axis_xy_px: tuple[float, float] | None = field(default=None)

    def __post_init__(self) -> None:
        for name in ("medium_ior", "immersion_ior", "coverslip_ior"):
            v = getattr(self, name)
            if not isinstance(v, int | float) or not math.isfinite(v) or not (1.0 <= v < 4.0):
                raise ConfigError(f"{name} must be a refractive index in [1, 4), got {v!r}")
        if not isinstance(self.na, int | float) or not (0 < self.na < self.immersion_ior):
            raise ConfigError(
                f"na must lie in (0, immersion_ior = {self.immersion_ior:g}), got {self.na!r}"
            )
        for name in ("coverslip_thickness_um", "coverslip_corrected_um"):
            v = getattr(self, name)
            if not isinstance(v, int | float) or not math.isfinite(v) or v < 0:
                raise ConfigError(f"{name} must be a finite thickness >= 0 µm, got {v!r}")
        if not isinstance(self.focus_depth_um, int | float) or not math.isfinite(
            self.focus_depth_um
        ):
            raise ConfigError(
                f"focus_depth_um must be a finite number, got {self.focus_depth_um!r}"
            )
        for name in (
            "f_objective_um",
            "f_tube_um",
            "mla_pitch_um",
            "mla_focal_um",
            "pixel_um",
            "wavelength_um",
            "mla_thickness_um",
        ):
            _positive(name, getattr(self, name))
        if self.mla_kind not in MLA_KINDS:
            raise ConfigError(f"mla_kind must be one of {MLA_KINDS}, got {self.mla_kind!r}")
        if not (1.0 < self.mla_ior < 4.0):
            raise ConfigError(f"mla_ior must lie in (1, 4), got {self.mla_ior!r}")
        sp = tuple(self.sensor_xy_px)
        if len(sp) != 2 or any(int(v) != v or v < 1 for v in sp):
            raise ConfigError(
                f"sensor_xy_px must be two positive integers, got {self.sensor_xy_px!r}"
            )
        object.__setattr__(self, "sensor_xy_px", (int(sp[0]), int(sp[1])))
        if sp[0] * sp[1] > MAX_SENSOR_PIXELS:
            raise ConfigError(
                f"sensor_xy_px {sp[0]} × {sp[1]} is too large: at most {MAX_SENSOR_PIXELS:,} "
                "pixels can be simulated"
            )
        if self.px_per_lenslet < 3:
            raise ConfigError(
                f"mla_pitch_um / pixel_um = {self.px_per_lenslet:.3g}: fewer than 3 pixels per "
                "lenslet cannot record a light field"
            )
        if self.mla_kind == "glass":
            r = self.lenslet_radius_of_curvature_um
            half_diag = self.mla_pitch_um / math.sqrt(2.0)
            if half_diag >= r:
                raise ConfigError(
                    f"glass lenslets of pitch {self.mla_pitch_um} µm and focal length "
                    f"{self.mla_focal_um} µm (radius {r:.4g} µm) cannot be spherical caps"
                )
            if self.mla_thickness_um <= self.lenslet_sag_um:
                raise ConfigError(
                    f"mla_thickness_um={self.mla_thickness_um} must exceed the lenslet sag "
                    f"{self.lenslet_sag_um:.3g} µm"
                )
        if self.axis_xy_px is None:
            w, h = self.sensor_xy_px
            p = self.px_per_lenslet
            axis = (
                math.floor(w / p / 2) * p + p / 2,
                math.floor(h / p / 2) * p + p / 2,
            )
            object.__setattr__(self, "axis_xy_px", axis)
        else:
            ax = tuple(float(v) for v in self.axis_xy_px)
            if len(ax) != 2 or not all(math.isfinite(v) for v in ax):
                raise ConfigError(f"axis_xy_px must be two finite numbers, got {self.axis_xy_px!r}")
            object.__setattr__(self, "axis_xy_px", ax)

    # -- derived quantities -------------------------------------------------------------
    @property
    def magnification(self) -> float:
        """Lateral magnification ``M`` of objective + tube lens."""
        return self.f_tube_um / self.f_objective_um

    @property
    def theta_max(self) -> float:
        """Half-angle (rad) of the acceptance cone in the immersion medium,
        ``asin(NA / n_immersion)``."""
        return math.asin(self.na / self.immersion_ior)

    @property
    def emission_half_angle(self) -> float:
        """Half-angle (rad) of the cone of rays, in the specimen, that can reach the sensor.

        ``n sin θ`` is conserved across planar interfaces, so it is
        ``asin(min(NA, n_medium, n_cover) / n_medium)``: a specimen of lower index than the NA
        (a dry specimen under an oil objective) or a thinner cover glass index caps it.
        """
        caps = [self.na, self.medium_ior]
        if self.coverslip_thickness_um > 0:
            caps.append(self.coverslip_ior)
        return math.asin(min(caps) / self.medium_ior)

    @property
    def is_immersion(self) -> bool:
        """Whether the objective is designed for an immersion medium (``immersion_ior`` ≠ 1).

        An immersion objective is modelled as aplanatic: a ray of direction sine ``sin θ`` in
        the immersion medium crosses the back focal plane at ``f_obj · n_imm · sin θ`` (the
        sine condition), and a depth ``z`` in the immersion medium is imaged ``M² z / n_imm``
        from the image plane (the longitudinal magnification of an objective with its image
        in air). Both tracers carry each ray to its air-equivalent ray, the ray through its
        intercept with the nominal focal plane of slope ``n_imm · sin θ``, and image that with
        the thin lenses (:func:`lfsim.tracer.objective_rays`). A dry objective is the thin
        lens itself (stop at ``f_obj · tan θmax``)."""
        return self.immersion_ior != 1.0

    # -- the specimen ---------------------------------------------------------------------
    @property
    def has_interfaces(self) -> bool:
        """Whether any interface lies between the objective and the specimen (a specimen of
        another index than the immersion medium, or a cover glass present or corrected for)."""
        return (
            self.medium_ior != self.immersion_ior
            or self.coverslip_thickness_um > 0
            or self.coverslip_corrected_um > 0
        )

    @property
    def _coverslip_residual_um(self) -> float:
        """Paraxial focal shift of the cover glass the objective is not corrected for, in the
        immersion medium: ``(t − t₀)(1 − n_imm / n_cover)``."""
        dt = self.coverslip_thickness_um - self.coverslip_corrected_um
        return dt * (1.0 - self.immersion_ior / self.coverslip_ior)

    @cached_property
    def _focus(self) -> tuple[float, float]:
        """:meth:`_focus_terms`, computed once per optics (the tracers and the bank ask often)."""
        return self._focus_terms()

    def _focus_terms(self, n_quad: int = 2048) -> tuple[float, float]:
        """``(a, b)`` of the least-squares axial crossing ``Z(d) = a·d + b`` (nominal frame, µm)
        of the rays a point at true depth ``d`` below the specimen's surface sends into the
        objective, by Snell's law in closed form.

        A ray at angle θ in the specimen leaves the cover glass's front face at the lateral
        offset ``r = d tan θ + t tan θ_cover + t₀ (tan θ_imm − tan θ_glass,imm)`` with slope
        ``tan θ_imm`` (``n sin θ`` conserved), so it crosses the axis at
        ``Z_front + r / tan θ_imm``; the crossings are averaged with the weights
        ``tan² θ_imm`` that minimise the rays' mean squared distance from the axis point, over
        the emission cone (uniform in solid angle, midpoint rule in ``cos θ``).
        """
        import numpy as np

        c0 = math.cos(self.emission_half_angle)
        cos = c0 + (1.0 - c0) * (np.arange(n_quad) + 0.5) / n_quad
        sin = np.sqrt(1.0 - cos**2)
        s_i = self.medium_ior * sin / self.immersion_ior
        tan_i = s_i / np.sqrt(1.0 - s_i**2)
        slope = (sin / cos) / tan_i  # d(crossing)/d(depth) of each ray
        offset = np.zeros_like(sin)
        if self.coverslip_thickness_um > 0:
            s_c = self.medium_ior * sin / self.coverslip_ior
            offset += self.coverslip_thickness_um * s_c / np.sqrt(1.0 - s_c**2)
        if self.coverslip_corrected_um > 0:
            s_g = self.immersion_ior * s_i / self.coverslip_ior
            offset += self.coverslip_corrected_um * (tan_i - s_g / np.sqrt(1.0 - s_g**2))
        w = tan_i**2 / np.sum(tan_i**2)
        z_front = -self.focus_depth_um - self.coverslip_thickness_um
        return float(np.sum(w * slope)), float(z_front + np.sum(w * offset / tan_i))

    @property
    def native_plane_depth_um(self) -> float:
        """True depth (µm) of the native object plane below the specimen's near surface.

        The depth of the point whose rays converge, in the least-squares sense, on the nominal
        focal plane (:meth:`_focus_terms`). Paraxially it is
        ``(n_medium / n_imm) · (focus_depth_um + (t − t₀)(1 − n_imm / n_cover))``; the rays of a
        finite NA focus a little deeper (spherical aberration of the planar interfaces: +2.4 %
        of the shift at 0.2 NA into a gel of index 1.35). Negative when the native plane lies
        in front of the specimen (the specimen's depth scale continued through it). Without
        interfaces it is ``focus_depth_um``.
        """
        if not self.has_interfaces:
            return self.focus_depth_um
        a, b = self._focus
        return -b / a

    @property
    def paraxial_native_plane_depth_um(self) -> float:
        """The paraxial value of :attr:`native_plane_depth_um` (µm)."""
        if not self.has_interfaces:
            return self.focus_depth_um
        ratio = self.medium_ior / self.immersion_ior
        return ratio * (self.focus_depth_um + self._coverslip_residual_um)

    @property
    def focal_shift_um(self) -> float:
        """Distance (µm) from the nominal focal plane to the native object plane (positive: the
        native plane lies deeper, away from the objective). 0 without interfaces."""
        return self.native_plane_depth_um - self.focus_depth_um

    @property
    def surface_z_um(self) -> float:
        """Object ``z`` (µm) of the specimen's near surface: sources must lie beyond it
        (positive when the native plane lies in front of the specimen)."""
        return -self.native_plane_depth_um

    @property
    def axial_scale(self) -> float:
        """Ratio of apparent to true axial distances in the specimen: how far the least-squares
        focus moves per µm of true depth (:meth:`_focus_terms`); paraxially
        ``n_imm / n_medium`` (0.741 for a dry objective into a gel of index 1.35, 0.733 with
        the rays of 0.2 NA). 1 without interfaces."""
        if not self.has_interfaces:
            return 1.0
        return self._focus[0]

    @property
    def max_axial_scale(self) -> float:
        """Largest ratio of apparent to true depth over the rays a point sends into the
        objective: paraxially ``n_imm / n_medium``, ``tan θ_m / tan θ_imm`` at the cone's edge
        (the image of a depth reaches at most this far). 1 without interfaces."""
        if not self.has_interfaces:
            return 1.0
        theta = self.emission_half_angle
        s_i = min(self.medium_ior * math.sin(theta) / self.immersion_ior, 1 - 1e-9)
        edge = math.tan(min(theta, 1.5)) / math.tan(math.asin(s_i))
        return max(self.immersion_ior / self.medium_ior, edge)

    @property
    def stop_radius_um(self) -> float:
        """Aperture-stop radius in the objective's back focal plane: ``f_obj · tan θmax``
        for a dry objective, ``f_obj · NA`` (the sine condition) for an immersion objective
        (:attr:`is_immersion`)."""
        if self.is_immersion:
            return self.f_objective_um * self.na
        return self.f_objective_um * math.tan(self.theta_max)

    @property
    def cone_fraction(self) -> float:
        """Fraction of isotropic emission inside the cone that reaches the objective,
        ``(1 − cos θ)/2`` with θ the :attr:`emission_half_angle` in the specimen."""
        return 0.5 * (1.0 - math.cos(self.emission_half_angle))

    @property
    def image_na(self) -> float:
        """Image-side numerical aperture at the microlens array, ``sin(atan(r_stop/f_tube))``."""
        return math.sin(math.atan(self.stop_radius_um / self.f_tube_um))

    @property
    def lenslet_na(self) -> float:
        """Numerical aperture of one lenslet, ``sin(atan(p / 2 f_l))``."""
        return math.sin(math.atan(self.mla_pitch_um / (2.0 * self.mla_focal_um)))

    @property
    def px_per_lenslet(self) -> float:
        """Lenslet pitch in sensor pixels (15 for the paper's optics)."""
        return self.mla_pitch_um / self.pixel_um

    @property
    def object_pixel_um(self) -> float:
        """Sensor pixel size referred to object space, ``pixel_um / M`` (≈ 1.67 µm)."""
        return self.pixel_um / self.magnification

    @property
    def lenslet_object_um(self) -> float:
        """Lenslet pitch referred to object space, ``p / M`` (25 µm)."""
        return self.mla_pitch_um / self.magnification

    @property
    def sensor_xy_um(self) -> tuple[float, float]:
        """Sensor extent ``(width, height)`` in the sensor plane."""
        return (self.sensor_xy_px[0] * self.pixel_um, self.sensor_xy_px[1] * self.pixel_um)

    @property
    def field_of_view_xy_um(self) -> tuple[float, float, float, float]:
        """Object-space field of view ``(x_min, x_max, y_min, y_max)`` seen by the sensor: the
        x range, then the y range (µm)."""
        w, h = self.sensor_xy_px
        cx, cy = self.axis_xy_px
        s = self.object_pixel_um
        return ((0 - cx) * s, (w - cx) * s, (0 - cy) * s, (h - cy) * s)

    @property
    def lenslet_radius_of_curvature_um(self) -> float:
        """Radius of a plano-convex glass lenslet, ``f_l (n − 1)``."""
        return self.mla_focal_um * (self.mla_ior - 1.0)

    @property
    def lenslet_sag_um(self) -> float:
        """Sag of a glass lenslet at the corner of its square aperture."""
        r = self.lenslet_radius_of_curvature_um
        c = self.mla_pitch_um / math.sqrt(2.0)
        return r - math.sqrt(max(r * r - c * c, 0.0))

    @property
    def sensor_distance_um(self) -> float:
        """Distance from the lenslet vertex plane to the sensor.

        ``f_l`` for ideal lenslets. For a plano-convex glass array with its curved side facing
        the objective, the front principal plane lies at the vertices and the rear one
        ``t/n`` in front of the flat back, so the sensor sits at ``t (1 − 1/n) + f_l``.
        """
        if self.mla_kind == "ideal":
            return self.mla_focal_um
        t, n = self.mla_thickness_um, self.mla_ior
        return t * (1.0 - 1.0 / n) + self.mla_focal_um

    @property
    def sigma_mla_um(self) -> float:
        """Diffraction blur (Gaussian σ) of ray positions at the microlens array.

        Gaussian approximation of the objective's Airy spot in the native image plane,
        ``σ = 0.21 λ / NA_image`` (Zhang, Zerubia & Olivo-Marin, Appl. Opt. 46, 2007,
        paraxial wide-field case), with ``NA_image = NA / M``.
        """
        return 0.21 * self.wavelength_um / self.image_na

    @property
    def sigma_sensor_um(self) -> float:
        """Diffraction blur (Gaussian σ) of ray positions at the sensor.

        The same approximation applied to one lenslet's aperture, ``σ = 0.21 λ / NA_lenslet``.
        """
        return 0.21 * self.wavelength_um / self.lenslet_na

    @property
    def n_lenslets_xy(self) -> tuple[int, int]:
        """Number of whole or partial lenslets across the sensor ``(nx, ny)``."""
        w, h = self.sensor_xy_px
        p = self.px_per_lenslet
        cx, cy = self.axis_xy_px
        nx = math.floor((w - cx) / p + 0.5) + math.floor(cx / p + 0.5) + 1
        ny = math.floor((h - cy) / p + 0.5) + math.floor(cy / p + 0.5) + 1
        return nx, ny

    # -- coordinate maps ------------------------------------------------------------------
    def spot_spacing_px(self, z_um: float) -> float:
        """Predicted spacing of the spot grid made by a point at depth ``z_um``.

        A point at (apparent, paraxial: ``z · axial_scale``) depth z images ``M² |z|`` from
        the array; each lenslet projects it onto the
        sensor, so spots repeat every ``p (1 ± f_l / (M² |z|))`` — the sign depends on the side
        of focus (``+`` for z > 0 with this project's axes, where the image forms in front of
        the array).
        """
        if z_um == 0:
            raise ConfigError("the spot spacing is undefined on the native object plane")
        d = self.magnification**2 * z_um * self.axial_scale
        return self.px_per_lenslet * (1.0 + self.mla_focal_um / d)

    def to_dict(self) -> dict:
        """Plain-JSON representation (all fields, lengths in µm)."""
        d = asdict(self)
        d["sensor_xy_px"] = list(self.sensor_xy_px)
        d["axis_xy_px"] = list(self.axis_xy_px)
        return d

    def fingerprint_dict(self) -> dict:
        """:meth:`to_dict` with the keys named as the fingerprints and cache keys hash them
        (:data:`FINGERPRINT_KEYS`)."""
        from hrvbase.io import rename_keys

        return rename_keys(self.to_dict(), FINGERPRINT_KEYS)

    @classmethod
    def from_dict(cls, data: dict) -> Optics:
        """Inverse of :meth:`to_dict`; unknown keys are an error naming them. The optics of
        the files of the older layout (calibration files, ``recon.json``), whose
        sensor and axis are ``sensor_px`` and ``axis_px``, are read too."""
        for older, name in OLDER_KEYS.items():
            if name in data and older in data:
                raise ConfigError(f"optics have both {older!r} and {name!r}; keep {name!r}")
        data = {OLDER_KEYS.get(k, k): v for k, v in data.items()}
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ConfigError(f"unknown optics keys {unknown}; expected some of {sorted(known)}")
        missing = [f.name for f in fields(cls) if f.name in REQUIRED and f.name not in data]
        if missing:
            raise ConfigError(f"optics keys {missing} are missing (no built-in microscope)")
        kw = dict(data)
        for key in ("sensor_xy_px", "axis_xy_px"):
            if key in kw and kw[key] is not None:
                kw[key] = tuple(kw[key])
        return cls(**kw)


def paper_optics(**overrides) -> Optics:
    """The paper's optics (Table 1): 4×/0.2 NA, 100 µm / f 1000 µm lenslets, 1280 × 800 px,
    15 px per lenslet, 605 nm emission."""
    return Optics(**{**PAPER_OPTICS, **overrides})


def small_optics(**overrides) -> Optics:
    """Paper optics on a 20 × 20-lenslet sensor (300 × 300 px) for fast tests."""
    return paper_optics(**{"sensor_xy_px": (300, 300), **overrides})


#: A 40×/0.8 water objective (5 mm focal length behind the 200 mm tube lens) into water, through
#: a 170 µm cover glass it is corrected for, focused 50 µm beyond it, with f/25 lenslets of
#: 100 µm matched to its image-side NA.
WATER_40X_OPTICS = {
    "na": 0.8,
    "immersion_ior": 1.333,
    "medium_ior": 1.333,
    "f_objective_um": 5000.0,
    "mla_focal_um": 2500.0,
    "coverslip_thickness_um": 170.0,
    "coverslip_corrected_um": 170.0,
    "focus_depth_um": 50.0,
}
