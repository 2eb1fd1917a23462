"""The ``brdffit`` command line: a thin layer that parses arguments, calls one API function and prints or writes
its result. Exit codes: 0 success, 1 a fit did not converge, 2 bad input or usage."""

from __future__ import annotations

import argparse
import sys

from . import __version__, models

EXIT_OK, EXIT_NOT_CONVERGED, EXIT_BAD_INPUT = 0, 1, 2


def _cmd_models(args) -> int:
    for name in models.names():
        cls = models.lobe_class(name)
        model = models.get(name, channels=1)
        print(models.describe(cls))
        for spec in model.param_specs:
            fixed = ", fixed by default" if spec.fixed else ""
            print(f"    {spec.name:<10} {spec.kind:<6} default {spec.default:<8g} bounds [{spec.lower:g}, "
                  f"{spec.upper:g}] unit {spec.unit}{fixed}: {spec.doc}")
    return EXIT_OK


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every ``brdffit`` command."""
    parser = argparse.ArgumentParser(
        prog="brdffit",
        description="Fit analytic BRDF models to measured reflectance.",
        epilog="Examples:\n  brdffit models\n  brdffit --version",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"brdffit {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    p = sub.add_parser("models", help="list every lobe with its parameters, bounds and reference",
                       description="List every lobe with its parameters, bounds and reference.",
                       epilog="Example:\n  brdffit models", formatter_class=argparse.RawDescriptionHelpFormatter)
    p.set_defaults(run=_cmd_models)
    return parser


def main(argv=None) -> int:
    """Entry point of the ``brdffit`` console script; returns the exit code."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse exits 2 on usage errors and 0 on --help/--version
        return int(exc.code or 0)
    if not getattr(args, "run", None):
        parser.print_help()
        return EXIT_BAD_INPUT
    return args.run(args)


if __name__ == "__main__":
    sys.exit(main())
