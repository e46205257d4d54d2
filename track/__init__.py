"""track — see README; this package is built in its own issue."""

__version__ = "0.1.0"
