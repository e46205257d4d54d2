"""The bad-input corpus's machinery: the shared valid inputs, the case type and the runner.

The rules every case checks are those of docs/conventions.md §7-8 (see
``tests/test_bad_inputs.py``). Corpus modules (``tests/test_bad_inputs.py`` and the
``test_bad_inputs_*.py`` modules beside the packages' tests) each keep a ``CASES`` list of
:class:`Case` and run it with :func:`run_case` on the session's :func:`build_base` inputs (the
``corpus_base`` fixture of ``tests/conftest.py``).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import tifffile

ROOT = Path(__file__).resolve().parents[1]
SMALL = ROOT / "scenes" / "small.xml"

#: Options of a fast reconstruction (tests/recon/test_pipeline.py).
FAST = ["--z-range=-40:400", "--z-step", "20", "-s", "3", "--rays-per-pattern", "20000"]

#: The experiment of the shared dataset: 3 frames, 6 particles, few rays (a few seconds).
EXPERIMENT = {
    "experiment": {"name": "corpus", "scene": "SCENE", "seed": 3, "frames": 3},
    "particles": {
        "kind": "box",
        "count": 6,
        "bounds_xyz_um": [[-180, 160], [-180, 160], [150, 350]],
        "min_spacing_um": 60,
        "diameter_um": 15,
    },
    "motion": {"type": "translation", "step_um": [5.0, 0.0, 0.0]},
    "render": {"rays_per_particle": 30000},
    "noise": {"model": "gaussian", "snr": 30},
    "white": {"rays_per_lenslet": 3000},
}

#: The study sections added to the experiment for ``hrvptm study``.
STUDY = {
    "study": {"kind": "series"},
    "recon": {
        "z_min_um": -40,
        "z_max_um": 400,
        "z_step_um": 20,
        "s": 3,
        "iterations": 1,
        "rays_per_pattern": 20000,
    },
    "track.grid": {"target_nodes": 1000},
}

DROP = object()

#: What the error says of an output below a regular file (``Env.blocker``).
BLOCKED = "blocker is a file, not a folder"


# -- small writers -----------------------------------------------------------------------------
def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, float) and math.isnan(v):
        return "nan"
    if isinstance(v, float) and math.isinf(v):
        return "inf" if v > 0 else "-inf"
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return repr(v)


def toml_text(sections: dict) -> str:
    """TOML text of ``{"section": {key: value}}`` (dotted section names for sub-tables)."""
    lines = []
    for name, table in sections.items():
        lines.append(f"[{name}]")
        lines += [f"{k} = {_toml_value(v)}" for k, v in table.items()]
        lines.append("")
    return "\n".join(lines)


def mutate(sections: dict, changes: dict) -> dict:
    """``sections`` with ``{"section.key": value}`` changes (``DROP`` removes the key; a new
    section name adds the section)."""
    out = {s: dict(t) for s, t in sections.items()}
    for path, value in changes.items():
        section, _, key = path.rpartition(".")
        table = out.setdefault(section, {})
        if value is DROP:
            table.pop(key, None)
        else:
            table[key] = value
    return out


def write_cloud(path: Path, xyz: np.ndarray) -> Path:
    lines = ["x_um,y_um,z_um"] + [",".join(f"{v:.6f}" for v in p) for p in xyz]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def snapshot(*roots: Path) -> dict[str, str]:
    """Every file (its SHA-256) and folder under ``roots``."""
    out = {}
    for root in roots:
        if not root.exists():
            continue
        for dirpath, _dirnames, filenames in os.walk(root):
            out[dirpath] = "folder"
            for name in filenames:
                p = os.path.join(dirpath, name)
                with open(p, "rb") as fh:
                    out[p] = hashlib.sha256(fh.read()).hexdigest()
    return out


# -- the shared valid inputs -------------------------------------------------------------------
@dataclass
class Base:
    root: Path
    scene: Path  # copy of scenes/small.xml
    scene_na025: Path  # same microscope, NA 0.25
    scene_200: Path  # a 200 x 200 px sensor
    scene_pitch: Path  # lenslets of another pitch
    exp: Path  # experiment TOML (own folder)
    ds: Path  # lfsim dataset folder
    calib: Path  # recon calibrate of ds/white.tif
    vol: Path  # recon run of ds (3 volumes)
    trk: Path  # track run of vol
    clouds: list[Path]  # 3 point clouds (own folder)
    particles: Path  # particle table for lfsim render
    study: Path  # study TOML (own folder)
    report: Path  # a finished (fake) hrvptm report

    @property
    def white(self) -> Path:
        return self.ds / "white.tif"

    @property
    def frames(self) -> list[Path]:
        return sorted((self.ds / "frames").glob("*.tif"))


def build_base(tmp_path_factory) -> Base:
    """Build the shared valid inputs (a few seconds; the ``corpus_base`` fixture)."""
    from hrvptm.cli import main as hrvptm_main
    from lfsim import small_optics
    from lfsim.cli import main as lfsim_main
    from lfsim.particles import Particles
    from lfsim.scene import write_scene
    from recon.cli import main as recon_main
    from track.cli import main as track_main

    root = tmp_path_factory.mktemp("corpus")
    (root / "scene").mkdir()
    scene = root / "scene" / "small.xml"
    shutil.copyfile(SMALL, scene)
    scene_na025 = write_scene(small_optics(na=0.25), root / "scene" / "na025.xml")
    scene_200 = write_scene(small_optics(sensor_xy_px=(200, 200)), root / "scene" / "s200.xml")
    scene_pitch = write_scene(small_optics(mla_pitch_um=125.0), root / "scene" / "p125.xml")
    (root / "exp").mkdir()
    exp = root / "exp" / "exp.toml"
    exp.write_text(toml_text(mutate(EXPERIMENT, {"experiment.scene": str(scene)})))
    ds = root / "ds"
    assert lfsim_main(["-q", "dataset", str(exp), "-o", str(ds)]) == 0
    calib = root / "calib.json"
    args = ["-q", "calibrate", str(ds / "white.tif"), "--scene", str(scene), "-o", str(calib)]
    assert recon_main(args) == 0
    vol = root / "vol"
    assert recon_main(["-q", "run", str(ds), *FAST, "--iterations", "1", "-o", str(vol)]) == 0
    trk = root / "trk"
    assert track_main(["-q", "run", str(vol), "-o", str(trk), "--allow-partial"]) == 0
    (root / "clouds").mkdir()
    rng = np.random.default_rng(11)
    xyz = rng.uniform([0, 0, 0], [400, 400, 300], (60, 3))
    clouds = [
        write_cloud(root / "clouds" / f"{k:06d}.csv", xyz + np.array([2.0 * k, 0, 0]))
        for k in range(3)
    ]
    particles = Particles(np.array([[0.0, 0.0, 150.0], [-80.0, 60.0, 250.0]])).to_csv(
        root / "p.csv"
    )
    (root / "study").mkdir()
    study = root / "study" / "study.toml"
    study.write_text(
        toml_text(mutate(EXPERIMENT | STUDY, {"experiment.scene": str(scene)})), encoding="utf-8"
    )
    report = root / "report"
    report.mkdir()
    (report / "summary.md").write_text("# study\n\nresults\n", encoding="utf-8")
    summary = {
        "study": {"experiment": {"experiment": {"name": "s", "frames": 2}}},
        "variants": {},
        "comparison": [],
        "plots": [],
    }
    (report / "summary.json").write_text(json.dumps(summary), encoding="utf-8")
    page = root / "page_probe" / "page.md"  # the fake report is collectable
    assert hrvptm_main(["-q", "collect", str(report), "-o", str(page)]) == 0
    shutil.rmtree(page.parent)
    return Base(
        root,
        scene,
        scene_na025,
        scene_200,
        scene_pitch,
        exp,
        ds,
        calib,
        vol,
        trk,
        clouds,
        particles,
        study,
        report,
    )


class Env:
    """What a case's argv builder gets: the shared inputs (``b``) and its own folder."""

    def __init__(self, b: Base, tmp: Path) -> None:
        self.b = b
        self.tmp = tmp
        self.inp = tmp / "in"
        self.inp.mkdir()

    def o(self, name: str = "out") -> Path:
        """An output path in the case's folder (not created)."""
        return self.tmp / name

    def w(self, name: str, data: str | bytes) -> Path:
        """Write a file of the case's inputs."""
        p = self.inp / name
        p.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(data, bytes):
            p.write_bytes(data)
        else:
            p.write_text(data, encoding="utf-8")
        return p

    def dir(self, name: str) -> Path:
        p = self.inp / name
        p.mkdir(parents=True)
        return p

    def tif(self, name: str, array, **kw) -> Path:
        p = self.inp / name
        p.parent.mkdir(parents=True, exist_ok=True)
        tifffile.imwrite(p, np.asarray(array), **kw)
        return p

    def trunc(self, src: Path, name: str, frac: float = 0.5) -> Path:
        data = src.read_bytes()
        return self.w(name, data[: int(len(data) * frac)])

    def blocker(self) -> Path:
        """A regular file, to put an output below it (we run as root: nothing is read-only)."""
        return self.w("blocker", "a file, not a folder\n")

    def existing(self, name: str = "existing.out") -> Path:
        """An existing output file, not an input."""
        p = self.tmp / name
        p.write_text("earlier result\n", encoding="utf-8")
        return p

    def foreign(self) -> Path:
        """A non-empty folder the tool did not write."""
        d = self.tmp / "foreign"
        d.mkdir()
        (d / "notes.txt").write_text("mine\n", encoding="utf-8")
        return d

    def exp_toml(self, changes: dict, name: str = "exp.toml", study: bool = False) -> Path:
        sections = EXPERIMENT | STUDY if study else EXPERIMENT
        changes = {"experiment.scene": str(self.b.scene), **changes}
        return self.w(name, toml_text(mutate(sections, changes)))

    def study_toml(self, changes: dict) -> Path:
        return self.exp_toml(changes, "study.toml", study=True)

    def calib(self, edit: Callable[[dict], object]) -> Path:
        data = json.loads(self.b.calib.read_text())
        new = edit(data)
        return self.w("calib.json", json.dumps(data if new is None else new))

    def voldir(self, edit: Callable[[Path], None] | None = None, name: str = "vol") -> Path:
        d = self.inp / name
        shutil.copytree(self.b.vol, d)
        if edit is not None:
            edit(d)
        return d

    def frames_dir(self, arrays: dict[str, np.ndarray], name: str = "frames") -> Path:
        d = self.dir(name)
        for n, a in arrays.items():
            tifffile.imwrite(d / n, a)
        return d

    def report(self, edit: Callable[[Path], None], name: str = "rep") -> Path:
        d = self.inp / name
        shutil.copytree(self.b.report, d)
        edit(d)
        return d


# -- the cases ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class Case:
    """One bad input: ``argv(env)`` run by ``prog`` must fail with ``status`` and a one-line
    error containing ``needle`` (``kind="warning"``: exit 0 and a warning containing it;
    ``writes``: the command may leave outputs, its inputs are still checked)."""

    id: str
    prog: str
    argv: Callable[[Env], list]
    needle: str | Callable[[Env], str]
    status: int = 2
    kind: str = "error"
    writes: bool = False
    marks: tuple = field(default=())


def case_adder(cases: list[Case]) -> Callable[..., None]:
    """``case(id, prog, argv, needle, **kw)`` appending to ``cases``."""

    def case(id, prog, argv, needle, **kw) -> None:
        cases.append(Case(id, prog, argv, needle, **kw))

    return case


def study_argv(e: Env, toml: Path, out=None, *extra) -> list:
    """``hrvptm study TOML -o OUT *extra`` (``out`` default: a fresh output path)."""
    return ["study", toml, "-o", out or e.o("rep"), *extra]


def collect_argv(e: Env, *reports, out=None, extra=()) -> list:
    """``hrvptm collect REPORT... -o OUT *extra`` (default: the shared report, a fresh page)."""
    return ["collect", *(reports or [e.b.report]), "-o", out or e.o("page.md"), *extra]


def params(cases: list[Case]) -> list:
    """``pytest.param`` of each case, with its id and marks."""
    import pytest

    return [pytest.param(c, id=c.id, marks=c.marks) for c in cases]


# -- the runner --------------------------------------------------------------------------------
def _main(prog: str):
    if prog == "lfsim":
        from lfsim.cli import main
    elif prog == "recon":
        from recon.cli import main
    elif prog == "track":
        from track.cli import main
    else:
        from hrvptm.cli import main
    return main


RESULTS: list[dict] = []


def run_case(c: Case, base: Base, tmp_path: Path, capsys) -> None:
    """Run one case and check the corpus rules (module docstring of tests/test_bad_inputs.py)."""
    env = Env(base, tmp_path)
    argv = [str(a) for a in c.argv(env)]
    capsys.readouterr()  # what building the inputs printed
    needle = c.needle(env) if callable(c.needle) else c.needle
    roots = (base.root, ROOT / "scenes")
    before, before_case = snapshot(*roots), snapshot(tmp_path)
    rc = _main(c.prog)(argv)
    err = capsys.readouterr().err
    after, after_case = snapshot(*roots), snapshot(tmp_path)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith(f"{c.prog}: error: ")]
    inputs_before = {k: v for k, v in before_case.items() if k.startswith(str(env.inp))}
    inputs_after = {k: v for k, v in after_case.items() if k.startswith(str(env.inp))}
    record = {
        "id": c.id,
        "rc": rc,
        "line": errors[-1] if errors else (lines or [""])[-1],
        "traceback": "Traceback" in err or "internal error" in err,
        "silent": rc == 0 and c.kind != "warning",
        "changed_inputs": before != after or inputs_before != inputs_after,
        "left_outputs": not c.writes and before_case != after_case,
    }
    RESULTS.append(record)
    report = os.environ.get("HRVPTM_CORPUS_REPORT")
    if report:
        with open(report, "a", encoding="utf-8") as fh:
            fh.write(json.dumps(record, ensure_ascii=False) + "\n")

    assert not record["traceback"], err
    assert before == after, "a shared input changed"
    if c.kind == "warning":
        assert rc == 0, err
        assert not errors, err
        assert any(ln.startswith(f"{c.prog}: warning: ") and needle in ln for ln in lines), err
    else:
        assert rc == c.status, f"exit {rc}, expected {c.status}: {err}"
        assert len(errors) == 1, err
        assert lines[-1] == errors[0], err
        assert all(ln.startswith(f"{c.prog}: warning: ") for ln in lines[:-1]), err
        assert needle in errors[0], errors[0]
    assert inputs_before == inputs_after, "an input of the case changed"
    if not c.writes:
        added = sorted(set(after_case) - set(before_case))
        assert before_case == after_case, f"outputs created or changed: {added}"
