"""Mitsuba scene files of the light-field microscope: write, read back, load.

A scene file (``scenes/*.xml``) is an ordinary Mitsuba 3 XML scene, in millimetres, with the
microlens array at the origin and light travelling along +z (docs/conventions.md):

====================  =========================================================
id                    element
====================  =========================================================
``objective``         ``lfm_thinlens`` at ``z = −2 f_tube − f_obj``
``aperture_stop``     ``lfm_aperture`` at ``z = −2 f_tube`` (radius sets the NA)
``tube_lens``         ``lfm_thinlens`` at ``z = −f_tube``
``mla``               ideal: ``lfm_lensletarray`` at ``z = 0``; glass: a ``null`` plane
                      just in front of the lenslet vertices, followed by the
                      instanced spherical-cap mesh (``mla_lenslet_*``) and the flat
                      back ``mla_back`` (``dielectric``)
``sensor``            ``lfm_sensor`` at the lenslets' back focal plane
``specimen_surface``  with a specimen interface: ``dielectric`` plane at the
                      specimen's near surface (interior: the specimen)
``coverslip_front``   with a cover glass: ``dielectric`` plane at its face
                      towards the objective (interior: the glass)
``coverslip_correction``  with a corrected cover-glass thickness: a ``null``
                      plane just in front of the cover glass, where the tracer
                      undoes that thickness of glass (:func:`lfsim.tracer.to_immersion`)
====================  =========================================================

The nominal focal plane lies at ``z = −2 f_tube − 2 f_obj``; the native object plane lies
:attr:`~lfsim.optics.Optics.focal_shift_um` beyond it (towards −z), the specimen's near surface
``focus_depth_um`` in front of it. The file starts with one
``<default>`` per :class:`~lfsim.optics.Optics` field: that block is what
:func:`read_optics` returns, and it checks that every element agrees with it, so a file edited
by hand either stays consistent or fails with a message naming the element.
"""

from __future__ import annotations

import hashlib
import math
import os
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass, fields
from pathlib import Path

from hrvbase.io import atomic_write_text

from .errors import SceneError
from .mesh import lenslet_array_mesh, write_ply
from .optics import Optics

UM_PER_MM = 1000.0

#: Optics fields written as ``<default>`` entries, with their XML names.
_SCALAR_FIELDS = [
    f.name for f in fields(Optics) if f.name not in ("sensor_xy_px", "axis_xy_px", "mla_kind")
]


# -- geometry shared by the writer, the reader's checks and the tracers -------------------
@dataclass(frozen=True)
class Layout:
    """Axial positions (mm) of the optical elements in scene coordinates."""

    object_z: float
    objective_z: float
    stop_z: float
    tube_z: float
    mla_z: float
    sensor_z: float
    surface_z: float
    coverslip_front_z: float

    @classmethod
    def of(cls, optics: Optics) -> Layout:
        fo = optics.f_objective_um / UM_PER_MM
        ft = optics.f_tube_um / UM_PER_MM
        nominal = -2 * ft - 2 * fo
        surface = nominal + optics.focus_depth_um / UM_PER_MM
        return cls(
            object_z=nominal - optics.focal_shift_um / UM_PER_MM,
            objective_z=-2 * ft - fo,
            stop_z=-2 * ft,
            tube_z=-ft,
            mla_z=0.0,
            sensor_z=optics.sensor_distance_um / UM_PER_MM,
            surface_z=surface,
            coverslip_front_z=surface + optics.coverslip_thickness_um / UM_PER_MM,
        )


def _radii_mm(optics: Optics) -> tuple[float, float]:
    """Clear radii of objective and tube lens that pass the whole field without vignetting."""
    x0, x1, y0, y1 = optics.field_of_view_xy_um
    field_r = math.hypot(max(abs(x0), abs(x1)), max(abs(y0), abs(y1))) / UM_PER_MM
    stop_r = optics.stop_radius_um / UM_PER_MM
    r_obj = 1.2 * (field_r + stop_r) + 1.0
    r_tube = 1.2 * (optics.magnification * field_r + stop_r) + 1.0
    return r_obj, r_tube


def sensor_rect_mm(optics: Optics) -> tuple[float, float, float, float]:
    """Sensor rectangle ``(x_center, y_center, half_w, half_h)`` in scene mm.

    Pixel column ``c`` sits at ``X = (axis_x − c) · pixel`` (the 4f image is inverted; reading
    columns along −X makes object +x run along +columns), rows likewise along −Y.
    """
    w, h = optics.sensor_xy_px
    ax, ay = optics.axis_xy_px
    p = optics.pixel_um / UM_PER_MM
    return ((ax - w / 2) * p, (ay - h / 2) * p, w / 2 * p, h / 2 * p)


def lenslet_centers_mm(optics: Optics, margin: int = 1) -> list[tuple[float, float]]:
    """Centres (mm) of every lenslet over the sensor, plus ``margin`` rings around it."""
    xc, yc, hw, hh = sensor_rect_mm(optics)
    p = optics.mla_pitch_um / UM_PER_MM
    i0 = math.floor((xc - hw) / p) - margin
    i1 = math.ceil((xc + hw) / p) + margin
    j0 = math.floor((yc - hh) / p) - margin
    j1 = math.ceil((yc + hh) / p) + margin
    return [(i * p, j * p) for j in range(j0, j1 + 1) for i in range(i0, i1 + 1)]


# -- writer ---------------------------------------------------------------------------------
def _fmt(v: float) -> str:
    return repr(float(v))


def _rect(parent, sid, x, y, z, hw, hh):
    shape = ET.SubElement(parent, "shape", type="rectangle", id=sid)
    tr = ET.SubElement(shape, "transform", name="to_world")
    ET.SubElement(tr, "scale", x=_fmt(hw), y=_fmt(hh), z="1")
    ET.SubElement(tr, "translate", x=_fmt(x), y=_fmt(y), z=_fmt(z))
    return shape


def _bsdf(parent, btype, **props):
    b = ET.SubElement(parent, "bsdf", type=btype)
    for k, v in props.items():
        tag = "integer" if isinstance(v, int) else "float"
        ET.SubElement(b, tag, name=k, value=str(v) if isinstance(v, int) else _fmt(v))
    return b


MESH_FACETS = 8


def lenslet_mesh_name(optics: Optics) -> str:
    """File name of the array mesh for these optics (hash of the geometry that shapes it)."""
    key = repr(
        (
            optics.mla_pitch_um,
            optics.lenslet_radius_of_curvature_um,
            optics.sensor_xy_px,
            optics.axis_xy_px,
            optics.pixel_um,
            MESH_FACETS,
        )
    )
    return f"mla_{hashlib.sha1(key.encode()).hexdigest()[:12]}.ply"


def ensure_mesh(optics: Optics, path: Path) -> Path:
    """Generate the glass array mesh at ``path`` unless it already exists (deterministic)."""
    if not path.is_file():
        path.parent.mkdir(parents=True, exist_ok=True)
        p = optics.mla_pitch_um / UM_PER_MM
        v, n, f = lenslet_array_mesh(
            lenslet_centers_mm(optics),
            p,
            optics.lenslet_radius_of_curvature_um / UM_PER_MM,
            MESH_FACETS,
        )
        write_ply(path, v, n, f)
    return path


def write_scene(optics: Optics, path: str | os.PathLike, *, description: str = "") -> Path:
    """Write a Mitsuba XML scene (and, for glass arrays, its lenslet PLY) for ``optics``.

    Parameters
    ----------
    optics : Optics
    path : path
        Output ``.xml``; a glass array's mesh goes to ``meshes/`` beside it.
    description : str
        Free text placed in a comment at the top.

    Returns
    -------
    Path of the written file (written atomically).
    """
    path = Path(path)
    lay = Layout.of(optics)
    root = ET.Element("scene", version="3.0.0")
    root.text = "\n"
    if description:
        root.append(ET.Comment(f" {description} "))
    root.append(
        ET.Comment(
            " Light-field microscope for hrvptm/lfsim. Units: mm; MLA at z = 0; light along +z."
            " The <default> block is the typed optics (µm) read back by lfsim.scene.read_optics;"
            " regenerate with `lfsim scene` rather than editing elements by hand. "
        )
    )
    for name in _SCALAR_FIELDS:
        ET.SubElement(root, "default", name=name, value=_fmt(getattr(optics, name)))
    ET.SubElement(root, "default", name="mla_kind", value=optics.mla_kind)
    ET.SubElement(root, "default", name="sensor_width_px", value=str(optics.sensor_xy_px[0]))
    ET.SubElement(root, "default", name="sensor_height_px", value=str(optics.sensor_xy_px[1]))
    ET.SubElement(root, "default", name="axis_x_px", value=_fmt(optics.axis_xy_px[0]))
    ET.SubElement(root, "default", name="axis_y_px", value=_fmt(optics.axis_xy_px[1]))

    r_obj, r_tube = _radii_mm(optics)
    fo = optics.f_objective_um / UM_PER_MM
    ft = optics.f_tube_um / UM_PER_MM
    s = _rect(root, "objective", 0, 0, lay.objective_z, r_obj, r_obj)
    _bsdf(s, "lfm_thinlens", focal_mm=fo, radius_mm=r_obj)
    s = _rect(root, "aperture_stop", 0, 0, lay.stop_z, 2 * r_tube, 2 * r_tube)
    _bsdf(s, "lfm_aperture", radius_mm=optics.stop_radius_um / UM_PER_MM)
    s = _rect(root, "tube_lens", 0, 0, lay.tube_z, r_tube, r_tube)
    _bsdf(s, "lfm_thinlens", focal_mm=ft, radius_mm=r_tube)

    xc, yc, hw, hh = sensor_rect_mm(optics)
    p = optics.mla_pitch_um / UM_PER_MM
    mla_hw, mla_hh = hw + 2 * p, hh + 2 * p
    if optics.mla_kind == "ideal":
        s = _rect(root, "mla", xc, yc, lay.mla_z, mla_hw, mla_hh)
        _bsdf(s, "lfm_lensletarray", pitch_mm=p, focal_mm=optics.mla_focal_um / UM_PER_MM)
    else:
        mesh_name = lenslet_mesh_name(optics)
        ensure_mesh(optics, path.parent / "meshes" / mesh_name)
        # Diffraction marker plane 1 µm in front of the lenslet vertices.
        s = _rect(root, "mla", xc, yc, lay.mla_z - 1e-3, mla_hw, mla_hh)
        ET.SubElement(s, "bsdf", type="null")
        glass = ET.SubElement(root, "bsdf", type="dielectric", id="mla_glass")
        ET.SubElement(glass, "float", name="int_ior", value=_fmt(optics.mla_ior))
        ET.SubElement(glass, "float", name="ext_ior", value="1.0")
        caps = ET.SubElement(root, "shape", type="ply", id="mla_caps")
        ET.SubElement(caps, "string", name="filename", value=f"meshes/{mesh_name}")
        ET.SubElement(caps, "boolean", name="face_normals", value="false")
        tr = ET.SubElement(caps, "transform", name="to_world")
        ET.SubElement(tr, "translate", x="0", y="0", z=_fmt(lay.mla_z))
        ET.SubElement(caps, "ref", id="mla_glass")
        t = optics.mla_thickness_um / UM_PER_MM
        s = _rect(root, "mla_back", xc, yc, lay.mla_z + t, mla_hw, mla_hh)
        ET.SubElement(s, "ref", id="mla_glass")

    _write_specimen(root, optics, lay, 2.0 * r_obj)

    s = _rect(root, "sensor", xc, yc, lay.sensor_z, hw, hh)
    _bsdf(
        s,
        "lfm_sensor",
        width_px=int(optics.sensor_xy_px[0]),
        height_px=int(optics.sensor_xy_px[1]),
        pixel_um=optics.pixel_um,
        wavelength_nm=optics.wavelength_um * 1000.0,
    )
    ET.indent(root, space="    ")
    data = ET.tostring(root, encoding="unicode") + "\n"
    return atomic_write_text(path, data, overwrite=True)


def _dielectric(parent, sid, z, half, int_ior, ext_ior):
    s = _rect(parent, sid, 0, 0, z, half, half)
    _bsdf(s, "dielectric", int_ior=float(int_ior), ext_ior=float(ext_ior))
    return s


#: Offset (mm) of the cover-glass correction plane in front of the cover glass.
CORRECTION_GAP_MM = 1e-2


def _write_specimen(root, optics: Optics, lay: Layout, half: float) -> None:
    """The specimen's interfaces (rectangles normal to z, interior on the specimen's side).

    None for an immersion objective: its tracers carry the rays through the interfaces to
    their air-equivalent rays before the objective (:func:`lfsim.tracer.objective_rays`)."""
    if not optics.has_interfaces or optics.is_immersion:
        return
    n_m, n_i = optics.medium_ior, optics.immersion_ior
    if optics.coverslip_thickness_um > 0:
        _dielectric(root, "specimen_surface", lay.surface_z, half, n_m, optics.coverslip_ior)
        _dielectric(root, "coverslip_front", lay.coverslip_front_z, half, optics.coverslip_ior, n_i)
    elif n_m != n_i:
        _dielectric(root, "specimen_surface", lay.surface_z, half, n_m, n_i)
    if optics.coverslip_corrected_um > 0:
        # A disk, not a rectangle: Mitsuba merges rectangles of equal BSDFs (the glass array's
        # null diffraction plane) into one shape, and the tracer must tell the two apart.
        s = ET.SubElement(root, "shape", type="disk", id="coverslip_correction")
        tr = ET.SubElement(s, "transform", name="to_world")
        ET.SubElement(tr, "scale", x=_fmt(half), y=_fmt(half), z="1")
        ET.SubElement(
            tr, "translate", x="0", y="0", z=_fmt(lay.coverslip_front_z + CORRECTION_GAP_MM)
        )
        ET.SubElement(s, "bsdf", type="null")


#: Optics fields a scene file may omit (the specimen: files written before it was modelled
#: describe air behind a dry objective, which these defaults are).
OPTIONAL_FIELDS = (
    "immersion_ior",
    "coverslip_thickness_um",
    "coverslip_ior",
    "coverslip_corrected_um",
    "focus_depth_um",
)


# -- reader ---------------------------------------------------------------------------------
def _parse(path: Path) -> ET.Element:
    if not path.is_file():
        raise SceneError(f"scene file {str(path)!r} does not exist")
    try:
        return ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise SceneError(f"scene file {str(path)!r} is not valid XML: {exc}") from exc


def read_optics(path: str | os.PathLike) -> Optics:
    """Read the typed optics back from a scene file and check the elements agree with it.

    Raises
    ------
    SceneError
        Missing file, missing ``<default>`` entries or elements, or an element whose values
        disagree with the optics block (the message names the element and both values).
    """
    path = Path(path)
    root = _parse(path)
    if root.tag != "scene":
        raise SceneError(f"{path}: root element is <{root.tag}>, expected <scene>")
    defaults = {d.get("name"): d.get("value") for d in root.findall("default")}
    needed = [
        *(f for f in _SCALAR_FIELDS if f not in OPTIONAL_FIELDS),
        "mla_kind",
        "sensor_width_px",
        "sensor_height_px",
    ]
    missing = [k for k in needed if k not in defaults]
    if missing:
        raise SceneError(
            f"{path}: missing optics <default> entries {missing}; is this an lfsim scene? "
            "(write one with `lfsim scene`)"
        )
    kw: dict = {}
    try:
        for name in _SCALAR_FIELDS:
            if name in defaults:
                kw[name] = float(defaults[name])
        kw["sensor_xy_px"] = (int(defaults["sensor_width_px"]), int(defaults["sensor_height_px"]))
        if "axis_x_px" in defaults:
            kw["axis_xy_px"] = (float(defaults["axis_x_px"]), float(defaults["axis_y_px"]))
    except (TypeError, ValueError) as exc:
        raise SceneError(f"{path}: a <default> optics value is not a number: {exc}") from exc
    kw["mla_kind"] = defaults["mla_kind"]
    try:
        optics = Optics(**kw)
    except SceneError:
        raise
    except ValueError as exc:
        raise SceneError(f"{path}: {exc}") from exc
    _check_elements(path, root, optics)
    return optics


def _shape(path, root, sid):
    for s in root.findall("shape"):
        if s.get("id") == sid:
            return s
    raise SceneError(f"{path}: no <shape id={sid!r}>; every lfsim scene needs one")


def _prop(path, elem, sid, name):
    b = elem.find("bsdf")
    for child in b if b is not None else []:
        if child.get("name") == name:
            return float(child.get("value"))
    raise SceneError(f"{path}: element {sid!r} has no property {name!r}")


def _z(elem) -> float:
    tr = elem.find("transform")
    t = tr.find("translate") if tr is not None else None
    return float(t.get("z", 0.0)) if t is not None else 0.0


def _check(path, sid, what, got, want, rtol=1e-9, atol=1e-12):
    if not math.isclose(got, want, rel_tol=rtol, abs_tol=atol):
        raise SceneError(
            f"{path}: element {sid!r} has {what}={got!r} but the optics block implies {want!r}; "
            "edit the <default> block and regenerate the scene with `lfsim scene`"
        )


def _check_elements(path: Path, root: ET.Element, optics: Optics) -> None:
    lay = Layout.of(optics)
    checks = [
        ("objective", "focal_mm", optics.f_objective_um / UM_PER_MM, lay.objective_z),
        ("tube_lens", "focal_mm", optics.f_tube_um / UM_PER_MM, lay.tube_z),
        ("aperture_stop", "radius_mm", optics.stop_radius_um / UM_PER_MM, lay.stop_z),
    ]
    for sid, prop, want, z in checks:
        e = _shape(path, root, sid)
        _check(path, sid, prop, _prop(path, e, sid, prop), want)
        _check(path, sid, "z (mm)", _z(e), z)
    sensor = _shape(path, root, "sensor")
    _check(path, "sensor", "z (mm)", _z(sensor), lay.sensor_z)
    _check(path, "sensor", "pixel_um", _prop(path, sensor, "sensor", "pixel_um"), optics.pixel_um)
    _check(
        path,
        "sensor",
        "width_px",
        _prop(path, sensor, "sensor", "width_px"),
        optics.sensor_xy_px[0],
    )
    _check(
        path,
        "sensor",
        "height_px",
        _prop(path, sensor, "sensor", "height_px"),
        optics.sensor_xy_px[1],
    )
    _check_specimen(path, root, optics, lay)
    mla = _shape(path, root, "mla")
    if optics.mla_kind == "ideal":
        p = optics.mla_pitch_um / UM_PER_MM
        _check(path, "mla", "pitch_mm", _prop(path, mla, "mla", "pitch_mm"), p)
        _check(
            path, "mla", "focal_mm", _prop(path, mla, "mla", "focal_mm"), optics.mla_focal_um / 1e3
        )
    else:
        back = _shape(path, root, "mla_back")
        _check(path, "mla_back", "z (mm)", _z(back), optics.mla_thickness_um / UM_PER_MM)
        glass = next((b for b in root.findall("bsdf") if b.get("id") == "mla_glass"), None)
        if glass is None:
            raise SceneError(f"{path}: glass array without <bsdf id='mla_glass'>")
        ior = next(float(c.get("value")) for c in glass if c.get("name") == "int_ior")
        _check(path, "mla_glass", "int_ior", ior, optics.mla_ior)
        caps = _shape(path, root, "mla_caps")
        fname = next((c.get("value") for c in caps if c.get("name") == "filename"), "")
        if fname != f"meshes/{lenslet_mesh_name(optics)}":
            raise SceneError(
                f"{path}: element 'mla_caps' uses mesh {fname!r}, which does not belong to this "
                f"scene's optics (expected 'meshes/{lenslet_mesh_name(optics)}'); regenerate the "
                "scene with `lfsim scene`"
            )


def _check_specimen(path: Path, root: ET.Element, optics: Optics, lay: Layout) -> None:
    """The specimen's planes are where the optics block puts them, with its indices."""
    ids = {s.get("id") for s in root.findall("shape")}
    want: list[tuple[str, float, float | None, float | None]] = []
    if optics.has_interfaces and not optics.is_immersion:
        n_m, n_i = optics.medium_ior, optics.immersion_ior
        if optics.coverslip_thickness_um > 0:
            want += [
                ("specimen_surface", lay.surface_z, n_m, optics.coverslip_ior),
                ("coverslip_front", lay.coverslip_front_z, optics.coverslip_ior, n_i),
            ]
        elif n_m != n_i:
            want.append(("specimen_surface", lay.surface_z, n_m, n_i))
        if optics.coverslip_corrected_um > 0:
            want.append(
                ("coverslip_correction", lay.coverslip_front_z + CORRECTION_GAP_MM, None, None)
            )
    names = {w[0] for w in want}
    for sid in ("specimen_surface", "coverslip_front", "coverslip_correction"):
        if sid in ids and sid not in names:
            raise SceneError(
                f"{path}: element {sid!r} does not belong to the optics block's specimen; "
                "regenerate the scene with `lfsim scene`"
            )
    for sid, z, n_int, n_ext in want:
        e = _shape(path, root, sid)
        _check(path, sid, "z (mm)", _z(e), z)
        if n_int is not None:
            _check(path, sid, "int_ior", _prop(path, e, sid, "int_ior"), n_int)
            _check(path, sid, "ext_ior", _prop(path, e, sid, "ext_ior"), n_ext)


# -- loading into Mitsuba ------------------------------------------------------------------
@dataclass
class LightFieldScene:
    """A loaded Mitsuba scene with its typed optics.

    Attributes
    ----------
    optics : Optics
    path : Path or None
        The XML it came from.
    mi_scene : mitsuba.Scene
    sensor, mla : mitsuba.Shape
        Shapes whose hits the tracer bins into pixels / blurs by diffraction.
    correction : mitsuba.Shape or None
        The plane where the tracer undoes the cover glass the objective is corrected for.
    interfaces : tuple of mitsuba.Shape
        The specimen's planes (interfaces and correction plane), far from the scene origin:
        the tracer continues rays from them along their new direction, not from an offset
        along the normal.
    layout : Layout
    """

    optics: Optics
    path: Path | None
    mi_scene: object
    sensor: object
    mla: object
    layout: Layout
    correction: object = None
    interfaces: tuple = ()


def load_scene(path: str | os.PathLike) -> LightFieldScene:
    """Read the optics of a scene file, check it, and load it into Mitsuba.

    Calls :func:`lfsim.init_backend` (default settings) if no backend is set yet.
    """
    from .backend import backend_info, init_backend

    path = Path(path)
    optics = read_optics(path)
    if optics.mla_kind == "glass":
        # The mesh is generated, not shipped: (re)create it beside the scene when missing.
        ensure_mesh(optics, path.parent / "meshes" / lenslet_mesh_name(optics))
    if backend_info() is None:
        init_backend()
    import mitsuba as mi

    try:
        scene = mi.load_file(str(path))
    except RuntimeError as exc:
        raise SceneError(f"Mitsuba cannot load {str(path)!r}: {exc}") from exc
    by_id = {s.id(): s for s in scene.shapes()}
    for sid in ("sensor", "mla"):
        if sid not in by_id:
            raise SceneError(f"{path}: loaded scene has no shape {sid!r}")
    return LightFieldScene(
        optics,
        path,
        scene,
        by_id["sensor"],
        by_id["mla"],
        Layout.of(optics),
        by_id.get("coverslip_correction"),
        tuple(
            by_id[k]
            for k in ("specimen_surface", "coverslip_front", "coverslip_correction")
            if k in by_id
        ),
    )


#: Version of the scene layout :func:`write_scene` writes (in the cache key of
#: :func:`scene_from_optics`).
SCENE_LAYOUT = 2


def scene_from_optics(optics: Optics, cache_dir: str | os.PathLike | None = None):
    """Write ``optics`` to a scene file in a cache folder and load it."""
    d = Path(cache_dir) if cache_dir else Path(tempfile.gettempdir()) / "lfsim_scenes"
    # the layout's version in the key: a scene cached by an earlier layout is not reused
    key = hashlib.sha1(repr((SCENE_LAYOUT, sorted(optics.to_dict().items()))).encode()).hexdigest()[
        :12
    ]
    path = d / f"scene_{key}.xml"
    if not path.is_file():
        write_scene(optics, path)
    return load_scene(path)
