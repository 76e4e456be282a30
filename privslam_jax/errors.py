"""The project's error type for input it cannot use.

:class:`InputError` is raised by every file reader (images and sequences, calibration, times,
poses, PLY, BAL, torch ``.pt`` and ``.npz`` checkpoints) when a file exists but its content is
wrong — truncated, corrupt, the wrong format, impossible sizes, values out of range — with a
message that names the file. It subclasses :class:`ValueError`, so code that catches
``ValueError`` keeps working; the CLI prints it as one line on stderr and exits with code 2.
A missing file stays a :class:`FileNotFoundError`.

:class:`PrivacyWarning` is warned when a privacy filter is about to run with a detector known to miss
objects in the frames at hand; the CLI shows it as one line on stderr.
"""

from __future__ import annotations

import os

__all__ = ["InputError", "PrivacyWarning", "input_error"]


class InputError(ValueError):
    """A file (or in-memory input) the project cannot use; the message names it."""


class PrivacyWarning(UserWarning):
    """The filter will leave people or vehicles visible (e.g. its detector's measured recall on such
    frames is low); the message says what was measured and how to raise recall."""


def input_error(path: str | os.PathLike, what: str, cause: BaseException | None = None) -> InputError:
    """``InputError("<path>: <what>[: <cause>]")`` — raise it ``from cause``."""
    detail = f": {type(cause).__name__}: {cause}" if cause is not None and str(cause) else (
        f": {type(cause).__name__}" if cause is not None else "")
    return InputError(f"{os.fspath(path)}: {what}{detail}")
