"""The files of this package's ``config/`` (graph, params, Fast DDS profile)."""

from __future__ import annotations

from pathlib import Path

PACKAGE = 'rover_bringup'


def config_file(name: str) -> Path:
    """A file of this package's ``config/``: the installed copy, else the source tree's."""
    try:
        from ament_index_python.packages import (
            PackageNotFoundError,
            get_package_share_directory,
        )

        installed = Path(get_package_share_directory(PACKAGE)) / 'config' / name
        if installed.is_file():
            return installed
    except (ImportError, PackageNotFoundError, ValueError):
        pass
    return Path(__file__).resolve().parent.parent / 'config' / name
