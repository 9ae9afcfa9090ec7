"""``bayescalib config-reference``: the configuration reference, from the schemas.

Prints the Markdown reference of every study key (type, default, bounds, meaning)
or writes it to ``--out`` (the repository keeps it as ``docs/config.md``).
"""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, default=None,
                   help="write the reference to this file (default: print it)")


def run(args: argparse.Namespace) -> int:
    from bayescalib.config_reference import reference_markdown
    from bayescalib.io._atomic_write import atomic_path

    text = reference_markdown()
    if args.out is None:
        print(text, end="")
        return 0
    with atomic_path(args.out, suffix=".md") as tmp:
        tmp.write_text(text)
    print(f"configuration reference -> {args.out}")
    return 0
