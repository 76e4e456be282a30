"""The project's error type for input it cannot use.

:class:`InputError` is raised by every file reader (images and sequences, calibration, times,
poses, PLY, BAL, torch ``.pt`` and ``.npz`` checkpoints) when a file exists but its content is
wrong — truncated, corrupt, the wrong format, impossible sizes, values out of range — with a
message that names the file. It subclasses :class:`ValueError`, so code that catches
``ValueError`` keeps working; the CLI prints it as one line on stderr and exits with code 2.
A missing file stays a :class:`FileNotFoundError`.
"""

from __future__ import annotations

import os

__all__ = ["InputError", "input_error"]


class InputError(ValueError):
    """A file (or in-memory input) the project cannot use; the message names it."""


def input_error(path: str | os.PathLike, what: str, cause: BaseException | None = None) -> InputError:
    """``InputError("<path>: <what>[: <cause>]")`` — raise it ``from cause``."""
    detail = f": {type(cause).__name__}: {cause}" if cause is not None and str(cause) else (
        f": {type(cause).__name__}" if cause is not None else "")
    return InputError(f"{os.fspath(path)}: {what}{detail}")
