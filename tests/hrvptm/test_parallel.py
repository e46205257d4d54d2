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
    monkeypatch.setattr("hrvbase.parallel.check_scheduler", lambda *a: None)  # none runs there
    monkeypatch.setattr("hrvbase.parallel.available_cores", lambda: 4)  # 2 workers: not capped
    demo = str(EXPERIMENTS / "demo_simple_shear.toml")
    assert main(["-q", "study", demo, "-o", str(tmp_path / "a"), "--workers", "2"]) == 0
    assert main(["-q", "study", demo, "-o", str(tmp_path / "b")]) == 0
    addr = "tcp://10.0.0.5:8786"
    assert main(["-q", "study", demo, "-o", str(tmp_path / "c"), "--scheduler", addr]) == 0
    assert seen == [Parallel(workers=2), Parallel(), Parallel(scheduler=addr)]


def test_stages_hand_parallel_to_the_tools(tmp_path, monkeypatch):
    import hrvptm.stages as stages
    from track.axial_bias import AxialCalibration

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
            axial = AxialCalibration()

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


def test_study_stages_share_one_local_cluster(tmp_path, monkeypatch):
    """--workers N: one local cluster for all the stages of a study (not one per stage)."""
    import hrvbase.parallel as hp
    import hrvptm.study as hs
    from hrvptm.config import load_study

    started, closed, got = [], [], []

    class FakeCluster:
        scheduler_address = "tcp://127.0.0.1:1"

        def close(self):
            closed.append(1)

    monkeypatch.setattr(hp, "_local_cluster", lambda par: started.append(par) or FakeCluster())
    for stage in ("simulate", "reconstruct", "track_stage"):
        monkeypatch.setattr(
            hs, stage, lambda *a, _s=stage, **k: got.append((_s, k["parallel"])) or 0.0
        )
    study = load_study(EXPERIMENTS / "demo_simple_shear.toml")
    hs.run_study(study, tmp_path / "r", until="track", progress=False, parallel=Parallel(workers=2))
    shared = Parallel(
        workers=2,
        scheduler=FakeCluster.scheduler_address,
        threads=Parallel(workers=2).worker_threads(),
    )
    assert started == [Parallel(workers=2)] and closed == [1]
    assert [s for s, _ in got] == ["simulate", "reconstruct", "track_stage"]
    assert all(p == shared for _, p in got)
