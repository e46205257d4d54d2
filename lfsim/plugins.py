"""Mitsuba BSDF plugins for microscope optics.

Names carry the prefix ``lfm_`` so that they never collide with Mitsuba's built-ins (there is a
``thinlens`` *camera* in Mitsuba). All are delta-transmissive: a ray that reaches them is either
redirected deterministically or absorbed (zero weight), which is what the light tracer in
:mod:`lfsim.tracer` expects. Units are those of the scene (millimetres in ``scenes/``).

- ``lfm_thinlens`` — ideal thin lens of focal length ``focal_mm`` centred on the shape's
  origin, clear radius ``radius_mm``. It maps ray slopes ``(u, v) → (u − x/f, v − y/f)``
  (paper Eq. 6 written with slopes, i.e. tangents, which makes it a perfect imager of planes).
- ``lfm_aperture`` — circular stop of radius ``radius_mm``: rays pass unchanged inside and are
  absorbed outside.
- ``lfm_lensletarray`` — ideal paraxial square lenslet array (paper Eq. 7, Georgiev &
  Intwala): pitch ``pitch_mm``, focal length ``focal_mm``, a lenslet centred at
  ``(center_x_mm, center_y_mm)`` in the shape's local frame; each ray is refracted by the
  lenslet that contains it, ``(u, v) → (u − (x − s_x)/f, v − (y − s_y)/f)``.
- ``lfm_sensor`` — the sensor: absorbs everything; holds the pixel grid
  (``width_px``, ``height_px``, ``pixel_um``) and the emission wavelength ``wavelength_nm``.

Plugins are registered by :func:`register_plugins`, which :func:`lfsim.init_backend` calls.
"""

from __future__ import annotations

_REGISTERED = False


def _make_classes():
    import drjit as dr
    import mitsuba as mi

    flags = mi.BSDFFlags.DeltaTransmission | mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide

    class _DeltaBSDF(mi.BSDF):
        """Common part: delta transmission, no eval/pdf."""

        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            self.m_flags = flags
            self.m_components = [flags]

        def _redirect(self, si, wo_world, ok):
            bs = dr.zeros(mi.BSDFSample3f)
            bs.wo = si.to_local(wo_world)
            bs.pdf = mi.Float(1.0)
            bs.eta = mi.Float(1.0)
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.DeltaTransmission)
            bs.sampled_component = mi.UInt32(0)
            weight = dr.select(ok, mi.Spectrum(1.0), mi.Spectrum(0.0))
            return bs, weight

        def eval(self, ctx, si, wo, active=True):
            return mi.Spectrum(0.0)

        def pdf(self, ctx, si, wo, active=True):
            return mi.Float(0.0)

        def eval_pdf(self, ctx, si, wo, active=True):
            return mi.Spectrum(0.0), mi.Float(0.0)

        def traverse(self, callback):
            pass

    def _slopes(si):
        d = si.to_world(-si.wi)
        return d, d.x / d.z, d.y / d.z

    def _from_slopes(u, v, dz_sign):
        return dr.normalize(mi.Vector3f(u * dz_sign, v * dz_sign, dz_sign))

    class ThinLens(_DeltaBSDF):
        def __init__(self, props):
            super().__init__(props)
            self.focal = float(props.get("focal_mm"))
            self.radius = float(props.get("radius_mm", 1e30))
            self.cx = float(props.get("center_x_mm", 0.0))
            self.cy = float(props.get("center_y_mm", 0.0))

        def sample(self, ctx, si, sample1, sample2, active=True):
            d, u, v = _slopes(si)
            x = si.p.x - self.cx
            y = si.p.y - self.cy
            ok = (x * x + y * y) <= self.radius * self.radius
            wo = _from_slopes(u - x / self.focal, v - y / self.focal, dr.sign(d.z))
            return self._redirect(si, wo, ok)

        def to_string(self):
            return f"LfmThinLens[focal_mm={self.focal}, radius_mm={self.radius}]"

    class Aperture(_DeltaBSDF):
        def __init__(self, props):
            super().__init__(props)
            self.radius = float(props.get("radius_mm"))
            self.cx = float(props.get("center_x_mm", 0.0))
            self.cy = float(props.get("center_y_mm", 0.0))

        def sample(self, ctx, si, sample1, sample2, active=True):
            x = si.p.x - self.cx
            y = si.p.y - self.cy
            ok = (x * x + y * y) <= self.radius * self.radius
            return self._redirect(si, si.to_world(-si.wi), ok)

        def to_string(self):
            return f"LfmAperture[radius_mm={self.radius}]"

    class LensletArray(_DeltaBSDF):
        def __init__(self, props):
            super().__init__(props)
            self.pitch = float(props.get("pitch_mm"))
            self.focal = float(props.get("focal_mm"))
            self.cx = float(props.get("center_x_mm", 0.0))
            self.cy = float(props.get("center_y_mm", 0.0))

        def sample(self, ctx, si, sample1, sample2, active=True):
            d, u, v = _slopes(si)
            sx = self.cx + self.pitch * dr.round((si.p.x - self.cx) / self.pitch)
            sy = self.cy + self.pitch * dr.round((si.p.y - self.cy) / self.pitch)
            uo = u - (si.p.x - sx) / self.focal
            vo = v - (si.p.y - sy) / self.focal
            return self._redirect(si, _from_slopes(uo, vo, dr.sign(d.z)), mi.Bool(True))

        def to_string(self):
            return f"LfmLensletArray[pitch_mm={self.pitch}, focal_mm={self.focal}]"

    class Sensor(_DeltaBSDF):
        def __init__(self, props):
            super().__init__(props)
            self.width_px = int(props.get("width_px"))
            self.height_px = int(props.get("height_px"))
            self.pixel_um = float(props.get("pixel_um"))
            self.wavelength_nm = float(props.get("wavelength_nm", 605.0))

        def sample(self, ctx, si, sample1, sample2, active=True):
            return self._redirect(si, si.to_world(-si.wi), mi.Bool(False))

        def to_string(self):
            return f"LfmSensor[{self.width_px}x{self.height_px} px, {self.pixel_um} um]"

    return {
        "lfm_thinlens": ThinLens,
        "lfm_aperture": Aperture,
        "lfm_lensletarray": LensletArray,
        "lfm_sensor": Sensor,
    }


def register_plugins() -> None:
    """Register the ``lfm_*`` BSDFs with Mitsuba (needs a variant set; idempotent)."""
    global _REGISTERED
    if _REGISTERED:
        return
    import mitsuba as mi

    for name, cls in _make_classes().items():
        mi.register_bsdf(name, lambda props, cls=cls: cls(props))
    _REGISTERED = True
