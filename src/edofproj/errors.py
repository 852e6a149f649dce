"""User-facing errors.

Every problem a user can fix (bad input, unreadable file, a sampling that cannot resolve
the optics) raises :class:`EdofprojError` with a one-line message that says what is wrong
and what is allowed. The CLI prints that line and exits with code 2, without a traceback.
"""


class EdofprojError(Exception):
    """An error caused by the user's input, reported as one line by the CLI."""


class DiskFullError(EdofprojError):
    """A write that failed because its disk (or the user's quota) is full; the message names the
    disk and what was kept (:func:`edofproj.fileio.disk_full_error`)."""


class ConfigError(EdofprojError):
    """A configuration key or value that does not exist or is out of range."""


class SamplingError(EdofprojError):
    """A simulation grid that cannot resolve the optics; the message names what to change."""


class BlurExceedsWindowWarning(UserWarning):
    """The geometric blur disk is wider than the PSF window: light outside it becomes haze."""


class SpectralSamplingWarning(UserWarning):
    """The wavelength sampling undersamples a primary's spectrum: the RGB PSFs are not converged."""


class ConfigConversionWarning(UserWarning):
    """A configuration in an older format was read by converting it; the message says what changed."""


class ProjectorWarning(UserWarning):
    """A design is simulated with a projector that was not read from its run (a design file without
    ``--config``: :mod:`edofproj.runs.projector`)."""


class RecoveryWarning(UserWarning):
    """edofproj recovered from an earlier fault (a stale lock taken over, temporary files of an
    interrupted write removed, a corrupt checkpoint skipped); the message says what it did."""


def require(condition: bool, message: str, error: type = EdofprojError) -> None:
    """Raise ``error(message)`` unless ``condition`` holds."""
    if not condition:
        raise error(message)
