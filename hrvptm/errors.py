"""Exceptions of :mod:`hrvptm` (the validation studies)."""

from __future__ import annotations

from hrvbase import errors as base


class StudyError(base.HrvError):
    """Base class of the errors ``hrvptm`` raises on purpose."""


class StudyConfigError(StudyError):
    """A study file or setting is invalid (the message names the file, key and expectation)."""


class ReportExistsError(StudyError):
    """The report folder holds another study's outputs or files not written by ``hrvptm``."""


class StageError(StudyError):
    """A pipeline stage could not produce what the comparison needs."""
