"""Every package's public API: each exported name exists, has its own entry in the package
docstring (a cross-reference with the role of its kind, not a substring of other text), and
its own docstring."""

from __future__ import annotations

import importlib
import inspect
import re

import pytest

PACKAGES = ["hrvbase", "lfsim", "recon", "track", "hrvptm"]
#: Names exported for convenience that a package docstring need not list.
UNLISTED = {"__version__", "errors", "io"}


def _roles(obj) -> tuple[str, ...]:
    """The Sphinx roles that may cross-reference ``obj`` (numpydoc / Sphinx conventions)."""
    if inspect.isclass(obj):
        return ("class", "exc")
    if inspect.ismodule(obj):
        return ("mod",)
    if callable(obj):
        return ("func",)
    return ("data", "attr")


def _entry(doc: str, name: str, roles: tuple[str, ...]) -> bool:
    """Whether ``doc`` cross-references ``name`` itself (``:func:`name```, ``:class:`~a.b.name```,
    ...), with one of ``roles``."""
    alt = "|".join(roles)
    return re.search(rf":(?:{alt}):`~?(?:[\w.]*\.)?{re.escape(name)}`", doc) is not None


def _own_doc(obj) -> str | None:
    """The docstring ``obj`` defines itself (a class's is not inherited from its base)."""
    if inspect.isclass(obj):
        return obj.__dict__.get("__doc__")
    if inspect.isfunction(obj) or inspect.ismodule(obj):
        return obj.__doc__
    return None


def test_an_entry_is_a_cross_reference_not_a_substring():
    doc = "- :class:`Optics`, :func:`small_optics` — the optics; ``GridSettings``, grid_axes"
    assert _entry(doc, "Optics", ("class",)) and _entry(doc, "small_optics", ("func",))
    assert not _entry(doc, "optics", ("func",))  # inside small_optics: not its entry
    assert not _entry(doc, "Optics", ("func",))  # the wrong kind
    assert not _entry(doc, "GridSettings", ("class",)) and not _entry(doc, "grid_axes", ("func",))
    assert _entry(":func:`~track.fields.grid_axes`", "grid_axes", ("func",))


@pytest.mark.parametrize("package", PACKAGES)
def test_exports_exist_and_are_documented(package):
    mod = importlib.import_module(package)
    missing = [name for name in mod.__all__ if not hasattr(mod, name)]
    assert not missing, f"{package}.__all__ names {missing}, which do not exist"
    doc = mod.__doc__ or ""
    no_entry = [
        name
        for name in mod.__all__
        if name not in UNLISTED and not _entry(doc, name, _roles(getattr(mod, name)))
    ]
    assert not no_entry, f"{package}'s docstring has no entry (:class:/:func:/:mod:) for {no_entry}"
    no_doc = []
    for name in mod.__all__:
        obj = getattr(mod, name)
        if inspect.isclass(obj) or inspect.isfunction(obj):
            own = _own_doc(obj)
            summary = (own or "").strip().splitlines()[0] if (own or "").strip() else ""
            if not summary:
                no_doc.append(name)
    assert not no_doc, f"{package}: public names without a docstring of their own: {no_doc}"
