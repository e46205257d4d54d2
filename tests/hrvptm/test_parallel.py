"""`hrvptm study --workers / --scheduler` reaches every stage's tool (the tools' own tests check
that their parallel results equal the serial ones)."""

from __future__ import annotations

from pathlib import Path

import pytest

from hrvbase.parallel import Parallel
from hrvptm.cli import main

EXPERIMENTS = Path(__file__).resolve().parents[2] / "scenes" / "experiments"


def test_study_passes_workers_and_scheduler_on(tmp_path, monkeypatch):
    seen = []
    monkeypatch.setattr("hrvptm.study.run_study", lambda *a, **k: seen.append(k["parallel"]))
    demo = str(EXPERIMENTS / "demo_simple_shear.toml")
    assert main(["-q", "study", demo, "-o", str(tmp_path / "a"), "--workers", "2"]) == 0
    assert main(["-q", "study", demo, "-o", str(tmp_path / "b")]) == 0
    addr = "tcp://10.0.0.5:8786"
    assert main(["-q", "study", demo, "-o", str(tmp_path / "c"), "--scheduler", addr]) == 0
    assert seen == [Parallel(workers=2), Parallel(), Parallel(scheduler=addr)]


def test_stages_hand_parallel_to_the_tools(tmp_path, monkeypatch):
    import hrvptm.stages as stages

    got = {}
    monkeypatch.setattr("lfsim.generate_dataset", lambda *a, **k: got.update(sim=k["parallel"]))
    monkeypatch.setattr(
        "track.pipeline.track_volumes", lambda *a, **k: got.update(track=k["parallel"])
    )

    class Study:
        class study:
            kind = "localization"

        class track:
            detect = series = None

    par = Parallel(workers=3)
    paths = stages.VariantPaths(tmp_path)
    stages.simulate(None, paths, parallel=par, progress=False)
    stages.track_stage(Study, paths, parallel=par, progress=False)
    assert got == {"sim": par, "track": par}


@pytest.mark.parametrize("value", ["0", "-4"])
def test_bad_workers_is_one_line(tmp_path, capsys, value):
    demo = str(EXPERIMENTS / "demo_simple_shear.toml")
    rc = main(["study", demo, "-o", str(tmp_path / "r"), f"--workers={value}"])
    assert rc == 2
    err = capsys.readouterr().err
    assert err == f"hrvptm: error: --workers must be an integer >= 1 or 'auto', got '{value}'\n"
    assert not (tmp_path / "r").exists()
