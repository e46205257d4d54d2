import re
import subprocess
from pathlib import Path

from hrvbase import revision
from hrvptm.report import _revision_line

ROOT = Path(__file__).resolve().parents[2]


def test_source_revision_names_the_checkout_commit():
    rev = revision.source_revision()
    if not (ROOT / ".git").exists():  # an exported tree: no revision to give
        assert rev is None
        return
    head = subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True, check=True
    ).stdout.strip()
    assert rev["commit"] == head and re.fullmatch(r"[0-9a-f]{40}", head)
    assert isinstance(rev["modified"], bool)


def test_source_revision_is_none_outside_a_checkout(tmp_path, monkeypatch):
    monkeypatch.setattr(revision, "_ROOT", tmp_path)
    revision.source_revision.cache_clear()
    try:
        assert revision.source_revision() is None
    finally:
        revision.source_revision.cache_clear()


def test_the_report_page_names_the_revision():
    sha = "0123456789abcdef" * 2 + "01234567"
    assert _revision_line({"commit": sha, "modified": False}) == ["- code: commit `0123456789ab`"]
    assert _revision_line({"commit": sha, "modified": True})[0].endswith("uncommitted changes")
    assert _revision_line(None) == [] and _revision_line({"commit": 3}) == []
