"""Docs, study files, packages and tests describe the project as it is.

A reader cannot know what a numbered work session or issue was, nor tell whether a statement
dated by one still holds; the development history lives in ``git log`` and ``CHANGELOG.md``.
So no text file of the docs, study files, packages, tests, benchmarks or the README may
name one: a measured value is stated with the command that shows it, an older value as a
comparison the reader can run again.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: Folders (every text file under them) and files searched, relative to the repository root.
SEARCHED = ("docs", "scenes", "hrvbase", "lfsim", "recon", "track", "hrvptm", "tests", "benchmarks")
SEARCHED += ("examples",)
#: Build outputs of the documentation site (docs/conf.py), not sources.
BUILT = {"_build", "auto_examples", "generated"}
SEARCHED_FILES = ("README.md",)

#: Suffixes of the text files read (plots and other binaries are skipped).
TEXT = {".md", ".py", ".toml", ".xml", ".json", ".csv", ".txt", ".cfg", ".ini", ".yaml", ".yml"}
TEXT |= {".rst"}

#: The word "session" or "issue" (any case, maybe plural) followed by a number, maybe after "#".
HISTORY = re.compile(r"\b(?:session|issue)s?\s*#?\s*\d+", re.IGNORECASE)


def _files() -> list[Path]:
    out = [ROOT / f for f in SEARCHED_FILES if (ROOT / f).is_file()]
    for top in SEARCHED:
        for path in sorted((ROOT / top).rglob("*")):
            built = {"__pycache__", *BUILT} & set(path.relative_to(ROOT).parts)
            if path.suffix in TEXT and path.is_file() and not built:
                out.append(path)
    return out


def _hits(text: str) -> list[tuple[int, str]]:
    return [
        (n, line.strip())
        for n, line in enumerate(text.splitlines(), start=1)
        if HISTORY.search(line)
    ]


def test_pattern_finds_numbered_sessions_and_issues() -> None:
    s, i = "session", "issue"  # spelled apart so that this file passes its own test
    hit = [f"{s} 8", f"({s.title()} 13)", f"{i} 12 §3", f"{i.title()} 12: x", f"{i} #13", f"{i}13"]
    miss = ["a pytest session", "the issue at hand", "reissue 3", "sessions of work"]
    assert all(HISTORY.search(s) for s in hit)
    assert not any(HISTORY.search(s) for s in miss)


def test_no_numbered_session_or_issue() -> None:
    found = []
    for path in _files():
        try:
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            continue
        found += [f"{path.relative_to(ROOT)}:{n}: {line}" for n, line in _hits(text)]
    assert not found, (
        "development history in the docs, study files, packages, tests or benchmarks (state "
        "what holds, with the command that shows it; history belongs in git log and "
        "CHANGELOG.md):\n" + "\n".join(found)
    )
