"""The version of nlpcal: the one place it is written (pyproject.toml reads it from here), a
constant so that `nlpcal --version` reads no package metadata."""

__version__ = "0.2.0"
