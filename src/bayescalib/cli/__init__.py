"""Command-line entry point ``bayescalib``.

Each sub-command lives in its own module ``bayescalib.cli.<name>`` that defines
``add_parser(subparsers)`` and ``run(args) -> int``; modules are imported only
when needed so that ``bayescalib --help`` stays fast. User errors
(:class:`bayescalib.config.ConfigError`, and other ``ValueError``/``OSError``
raised on bad input) are printed as one clear line and exit with status 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys

#: sub-command name -> (module, one-line help)
SUBCOMMANDS: dict[str, tuple[str, str]] = {}


def _register(name: str, module: str, help_: str) -> None:
    SUBCOMMANDS[name] = (module, help_)
_register("config-reference", "bayescalib.cli.config_reference",
          "Write the configuration reference (every study key) from the schemas.")
_register("distance", "bayescalib.cli.distance", "Discrepancy D between a model and an observed interface.")
_register("solve", "bayescalib.cli.solve", "Run one forward FSI solve and print a one-line JSON summary.")
_register("summary", "bayescalib.cli.summary", "Print a finished study's result (summary.json) as tables.")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="bayescalib",
        description=(
            "Bayesian calibration of coupled computational mechanics models from "
            "observed interface shapes."
        ),
    )
    from bayescalib import __version__

    parser.add_argument("--version", action="version", version=f"bayescalib {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name, (module, help_) in SUBCOMMANDS.items():
        mod = importlib.import_module(module)
        p = sub.add_parser(name, help=help_, description=help_)
        mod.add_parser(p)
        p.set_defaults(_module=module)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    mod = importlib.import_module(args._module)
    from bayescalib.config import ConfigError

    try:
        return int(mod.run(args) or 0)
    except (ConfigError, ValueError, OSError) as exc:
        print(f"bayescalib {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
