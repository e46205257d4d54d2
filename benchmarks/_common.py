"""What the tracking benchmarks share: their ``--baseline`` run of an older ``track`` and their
plain-text tables (imported by the scripts beside it, run from the repository root)."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def add_baseline_arguments(ap: argparse.ArgumentParser) -> None:
    """``--baseline REV``, ``--json PATH`` and the hidden ``--_worker PATH`` of a baseline run."""
    ap.add_argument("--baseline", metavar="REV", help="also run track of this git revision")
    ap.add_argument("--json", metavar="PATH", help="write all rows to this JSON file")
    ap.add_argument("--_worker", help=argparse.SUPPRESS)


def run_baseline_worker(
    script: str, rev: str, args: list[str], today: tuple[str, ...], prefix: str
):
    """Run ``script --_worker OUT *args`` with ``track`` and ``hrvbase`` of git revision ``rev``.

    The two packages are extracted with ``git archive`` to a temporary folder, the ``track``
    modules named in ``today`` are copied in from this checkout (the synthetic data), and the
    script runs in a subprocess with that folder first on ``PYTHONPATH``; returns what the
    worker wrote to ``OUT`` (JSON)."""
    with tempfile.TemporaryDirectory(prefix=prefix) as tmp:
        archive = subprocess.run(
            ["git", "archive", rev, "track", "hrvbase"], cwd=ROOT, capture_output=True, check=True
        ).stdout
        subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        for name in today:
            (Path(tmp) / "track" / name).write_bytes((ROOT / "track" / name).read_bytes())
        out = Path(tmp) / "rows.json"
        cmd = [sys.executable, str(Path(script).resolve()), "--_worker", str(out), *args]
        env = dict(os.environ, PYTHONPATH=tmp)
        subprocess.run(cmd, cwd=tmp, env=env, check=True)
        return json.loads(out.read_text())


def print_table(head: list[str], table: list[list[str]]) -> None:
    """Print ``head`` and the rows of ``table`` (strings) in left-aligned columns."""
    widths = [max(len(x[i]) for x in [head, *table]) for i in range(len(head))]
    for x in [head, *table]:
        print("  ".join(v.ljust(w) for v, w in zip(x, widths, strict=True)))
