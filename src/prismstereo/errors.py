"""Project exceptions.

Every error a user can cause (bad configuration, unreadable image, impossible geometry) is raised as a
subclass of :class:`PrismStereoError` with an "expected ..., got ..." message; the CLI turns these into
one line on stderr and exit code 2.
"""

from __future__ import annotations


class PrismStereoError(Exception):
    """Base class of every error the project raises on purpose."""


class ConfigError(PrismStereoError, ValueError):
    """A rig, scene or matcher configuration is missing keys, has unknown keys or impossible values."""


class ImageError(PrismStereoError, ValueError):
    """An image is unreadable, empty, has the wrong size, dtype or number of channels."""


class GeometryError(PrismStereoError, ValueError):
    """The optics cannot work as asked: total internal reflection, views that do not overlap, ..."""


class MatchingError(PrismStereoError, ValueError):
    """A matcher was asked for something impossible (disparity range wider than the image, ...)."""


class OutputError(PrismStereoError, OSError):
    """An output cannot be written (unwritable folder, ...)."""
