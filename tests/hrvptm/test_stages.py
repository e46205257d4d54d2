"""The stages' errors: a library error inside a stage is one line naming the stage's folder."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from hrvptm.errors import StageError
from hrvptm.stages import VariantPaths, track_stage
from track.detect import DetectSettings


def test_a_failing_stage_names_its_folder(tmp_path):
    """``track_stage`` on a variant without volumes: the tracking library's error, prefixed
    with the stage and the folder, as one StageError (no chained traceback)."""
    study = SimpleNamespace(
        study=SimpleNamespace(kind="localization"),
        track=SimpleNamespace(
            axial=SimpleNamespace(enabled=False), detect=DetectSettings(), series=None
        ),
    )
    paths = VariantPaths(tmp_path / "matched")
    with pytest.raises(StageError) as info:
        track_stage(study, paths, progress=False)
    message = str(info.value)
    assert message.startswith(f"tracking {paths.volumes}: ")
    assert str(paths.volumes) in message[len(f"tracking {paths.volumes}: ") :]
    assert "\n" not in message
    assert info.value.__suppress_context__
