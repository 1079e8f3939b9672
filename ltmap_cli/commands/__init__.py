"""One module per subcommand; each is imported only when its command runs."""

from __future__ import annotations

from pathlib import Path

import click


def nonempty_output(ctx: click.Context, param: click.Parameter, value: Path | None) -> Path | None:
    """Click callback of ``-o``: an empty path ('' becomes '.': the current folder) is refused,
    not written into."""
    if value is not None and str(value).strip() in ("", "."):
        raise click.BadParameter("-o '' or -o . names the current folder, which the output would replace; give "
                                 "an output path, e.g. -o out")
    return value
