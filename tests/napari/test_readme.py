"""README "Viewing results in napari": the commands from a fresh clone to the demo in napari."""

from __future__ import annotations

import re
import shlex
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
COMMANDS = [
    "./setup.sh",
    ".venv/bin/hrvptm demo -o out/demo",
    ".venv/bin/napari --plugin hrvptm out/demo",
]


def _commands() -> list[str]:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text.split("### Viewing results in napari", 1)[1].split("\n#", 1)[0]
    block = re.search(r"```bash\n(.*?)```", section, re.S).group(1)
    return [line for line in block.splitlines() if line.strip()]


def test_readme_gives_the_commands_and_setup_installs_the_plugin():
    assert _commands() == COMMANDS  # at most five, the ones the tests below run
    setup = (ROOT / "setup.sh").read_text(encoding="utf-8")
    assert "pip install -q -e '.[test]'" in setup and "xvfb" in setup
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert "hrvptm[napari]" in extras["optional-dependencies"]["test"]
    assert any(d.startswith("napari") for d in extras["optional-dependencies"]["napari"])
    eps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["entry-points"]
    assert eps["napari.manifest"] == {"hrvptm": "hrvptm_napari:napari.yaml"}


@pytest.mark.studies
def test_readme_demo_opens_in_napari(session_viewer, tmp_path, monkeypatch):
    """The README's demo and napari commands (``napari --plugin P PATH`` is
    ``viewer.open(PATH, plugin=P)``), in a temporary folder."""
    from hrvptm.cli import main

    monkeypatch.chdir(tmp_path)
    demo, view = (shlex.split(c) for c in COMMANDS[1:])
    assert main([*demo[1:], "-q"]) == 0
    assert view[1:3] == ["--plugin", "hrvptm"]
    session_viewer.layers.clear()
    layers = session_viewer.open(view[3], plugin=view[2])
    kinds = {layer.name: type(layer).__name__ for layer in layers}
    assert {k: kinds.get(k) for k in ("volumes", "particles", "tracks", "displacement",
                                      "truth", "E_xz")} == {
        "volumes": "Image", "particles": "Points", "tracks": "Tracks",
        "displacement": "Vectors", "truth": "Points", "E_xz": "Image",
    }  # fmt: skip
    vol = session_viewer.layers["volumes"]
    assert vol.data.shape[0] == 5 and len(vol.scale) == 4  # the demo's five frames
    session_viewer.layers.clear()
