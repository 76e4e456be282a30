"""The ``privslam`` command.

Each subcommand lives in ``privslam_jax/commands/<name>.py`` and exposes
``add_parser(subparsers)`` (which registers its arguments and sets ``func``).
Only commands that work are listed here.
"""

from __future__ import annotations

import argparse
import sys
import warnings

from privslam_jax._xla import configure_xla

# Module names under privslam_jax.commands, in the order `privslam --help` lists them.
_COMMANDS: tuple[str, ...] = ("run", "synth", "import_frames", "detect", "lift", "attack", "localize", "eval_points", "filter", "slam", "serve", "client")


def build_parser() -> argparse.ArgumentParser:
    import importlib

    parser = argparse.ArgumentParser(
        prog="privslam",
        description="Privacy-preserving edge-assisted visual SLAM in JAX.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in _COMMANDS:
        importlib.import_module(f"privslam_jax.commands.{name}").add_parser(sub)
    return parser


def _format_warning(message, category, filename, lineno, line=None) -> str:
    """A :class:`~privslam_jax.errors.PrivacyWarning` is the command's own message: one line, without
    the library's file, line and source text; other warnings as Python formats them."""
    from privslam_jax.errors import PrivacyWarning

    if issubclass(category, PrivacyWarning):
        return f"{message}\n"
    return _PYTHON_FORMAT(message, category, filename, lineno, line)


_PYTHON_FORMAT = warnings.formatwarning


def main(argv: list[str] | None = None) -> int:
    configure_xla()
    args = build_parser().parse_args(argv)
    warnings.formatwarning = _format_warning
    try:
        if not getattr(args, "owns_out", False):
            return int(args.func(args) or 0)
        # Commands that own their --out folder: claim it (manifest.json, "complete": false), run,
        # then mark it complete; a failed or killed run leaves "complete": false (privslam_jax/runs.py).
        from privslam_jax.runs import claim_run_folder, complete_run_folder

        arguments = {k: v for k, v in vars(args).items() if k not in ("func", "owns_out")}
        manifest = claim_run_folder(args.out, args.command, arguments, overwrite=args.overwrite)
        rc = int(args.func(args) or 0)
        if rc == 0:
            complete_run_folder(args.out, manifest)
        return rc
    except (OSError, ValueError) as err:  # bad input or a failed write: clear message, no traceback
        message = " ".join(str(err).split())  # one line, whatever the message holds
        print(f"privslam {args.command}: error: {message}", file=sys.stderr)
        return 2
    finally:
        warnings.formatwarning = _PYTHON_FORMAT


if __name__ == "__main__":
    raise SystemExit(main())
