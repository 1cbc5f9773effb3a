"""The exception hierarchy of towerpipe.

Every error a user can meet derives from :class:`TowerpipeError`. Messages are
one line that names the file (or config key) and the cause, and says what to do
about it where something can be done, e.g.::

    InputError: data/zone1/b7.laz: no CRS in the file; set `zones: {zone1: {crs: "EPSG:25831"}}` in the config
"""

from __future__ import annotations

from os import PathLike


class TowerpipeError(Exception):
    """Base class of all towerpipe errors."""


class ConfigError(TowerpipeError):
    """The configuration is invalid (names the key and the fix)."""


class InputError(TowerpipeError):
    """An input point cloud cannot be processed (names the file and the cause).

    Parameters
    ----------
    path
        The offending file.
    cause
        What is wrong with it, and what to do where something can be done.
    """

    def __init__(self, path: str | PathLike[str], cause: str):
        self.path = str(path)
        self.cause = cause
        super().__init__(f"{self.path}: {cause}")


class PdalError(TowerpipeError):
    """The ``pdal`` command-line tool is missing or a pipeline failed."""


class DiskSpaceError(TowerpipeError):
    """A disk has no room for what a step writes (names the directory or file and the fix).

    Parameters
    ----------
    path
        The directory or file that could not be written.
    cause
        How much room was needed and is free, and where to find more.
    """

    def __init__(self, path: str | PathLike[str], cause: str):
        self.path = str(path)
        self.cause = cause
        super().__init__(f"{self.path}: {cause}")


class ModelError(TowerpipeError):
    """A model file is missing, corrupt, or does not fit the data."""
