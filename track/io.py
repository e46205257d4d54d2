"""Backward-compatible façade: re-exports track.tables, track.field_files and track.volumes."""

from __future__ import annotations

from .field_files import (
    read_field_npz,
    read_field_time,
    read_field_vti,
    vti_arrays,
    vti_units,
    write_field_npz,
    write_field_vti,
)
from .tables import (
    MATCH_COLUMNS,
    MATCH_SIGMA_COLUMNS,
    POINT_COLUMNS,
    SIGMA_COLUMNS,
    TIME_COLUMN,
    TRACK_COLUMNS,
    VELOCITY_COLUMNS,
    read_match_sigmas,
    read_matches_csv,
    read_point_sigmas,
    read_points_csv,
    read_tracks_csv,
    write_matches_csv,
    write_points_csv,
    write_tracks_csv,
)
from .volumes import VolumeInfo, numbered, read_volume, scan_volumes

__all__ = [
    "MATCH_COLUMNS",
    "MATCH_SIGMA_COLUMNS",
    "POINT_COLUMNS",
    "SIGMA_COLUMNS",
    "TIME_COLUMN",
    "TRACK_COLUMNS",
    "VELOCITY_COLUMNS",
    "VolumeInfo",
    "numbered",
    "read_field_npz",
    "read_field_time",
    "read_field_vti",
    "read_match_sigmas",
    "read_matches_csv",
    "read_point_sigmas",
    "read_points_csv",
    "read_tracks_csv",
    "read_volume",
    "scan_volumes",
    "vti_arrays",
    "vti_units",
    "write_field_npz",
    "write_field_vti",
    "write_matches_csv",
    "write_points_csv",
    "write_tracks_csv",
]
