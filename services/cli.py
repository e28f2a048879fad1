"""The `replanner` command: the root app, joined from cli_service, cli_sim and cli_bench.

Imports flow one way: cli -> cli_service / cli_sim / cli_bench -> cli_common (see tests/test_cli.py).
"""

from __future__ import annotations

import logging
import sys

import typer

from replanner.errors import ReplannerError

from . import cli_bench, cli_service, cli_sim
from .cli_common import print_error

app = typer.Typer(
    help="replanner: reactive replanning for robot arms next to people.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
    rich_markup_mode="markdown",  # help text as written: "[s]" is a unit here, not a rich markup tag
)
app.add_typer(cli_service.app)  # serve, router, robot, goal, cancel, status, scene ...
app.add_typer(cli_sim.app)  # sim, cameras (hidden), pick-and-place, demo
app.add_typer(cli_bench.app, name="bench")


def main() -> None:
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    logging.getLogger("transitions").setLevel(logging.WARNING)  # replanner.controller logs each transition once
    try:
        app(prog_name="replanner")
    except ReplannerError as err:  # a command that let one through: the same red line and exit code as fail()
        print_error(err)
        sys.exit(2)


if __name__ == "__main__":
    main()
