"""The version of nlpcal, from the installed package's metadata (pyproject.toml is its source)."""

from __future__ import annotations

from importlib import metadata

try:
    __version__ = metadata.version("nlpcal")
except metadata.PackageNotFoundError:  # a checkout run without installing
    __version__ = "0+unknown"
