"""What every `replanner` command shares: the config option, the Zenoh flags, one error output.

The leaf of the CLI's imports: cli_bench, cli_service and cli_sim import this module and nothing of each
other; cli.py joins them into the root app.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated, Literal, NoReturn

import typer
from rich.console import Console
from rich.text import Text

from replanner.sim.config import CellConfig, load_cell_config

if TYPE_CHECKING:
    import zenoh

    from replanner.sections import TransportConfig

CONFIG_HELP = "Robot config: a YAML file, or the name of a shipped profile (panda, iiwa, demo)."
ROBOT_HELP = "Robot name; default: the config's."
JSON_HELP = "Print JSON instead of a table."
MODE_HELP = "Zenoh mode: peer (default), client or router."
CONNECT_HELP = "Zenoh endpoint to connect to, e.g. tcp/10.0.0.2:7447 (repeatable)."
LISTEN_HELP = "Zenoh endpoint to listen on, e.g. tcp/0.0.0.0:7448 (repeatable)."
ZCONF_HELP = "A Zenoh JSON5 config file, or a shipped one: client, router (the flags above still override it)."
ZENOH_PANEL = "Zenoh connection"

# The options, defined once; a command declares e.g. `config: ConfigOpt = "panda"` (the default is its own).
ConfigOpt = Annotated[str, typer.Option("--config", "-c", help=CONFIG_HELP)]
RobotOpt = Annotated[str | None, typer.Option("--robot", help=ROBOT_HELP)]
JsonOpt = Annotated[bool, typer.Option("--json", help=JSON_HELP)]
LoadOpt = Annotated[
    int,
    typer.Option(
        "--load", min=0, max=16, help="Busy processes beside the run (a busy machine), stopped at its end; in the JSON."
    ),
]

# zenoh-python's examples (common.py) add -m/--mode, -e/--connect, -l/--listen to every example the same way.
ModeOpt = Annotated[
    str | None, typer.Option("--mode", "-m", metavar="MODE", help=MODE_HELP, rich_help_panel=ZENOH_PANEL)
]
ConnectOpt = Annotated[
    list[str] | None,
    typer.Option("--connect", "-e", metavar="ENDPOINT", help=CONNECT_HELP, rich_help_panel=ZENOH_PANEL),
]
ListenOpt = Annotated[
    list[str] | None,
    typer.Option("--listen", "-l", metavar="ENDPOINT", help=LISTEN_HELP, rich_help_panel=ZENOH_PANEL),
]
ZenohConfigOpt = Annotated[
    str | None, typer.Option("--zenoh-config", metavar="FILE", help=ZCONF_HELP, rich_help_panel=ZENOH_PANEL)
]

_err_console = Console(stderr=True, soft_wrap=True)  # soft wrap: never break a path or a field name


def resolve_config(config: str) -> CellConfig:
    """A config file or a shipped profile by name, with the simulated cell's section (the demo's file serves all)."""
    return load_cell_config(config)


def print_error(err: BaseException) -> None:
    """`error: <message>` in red on stderr; the message is printed as is (no markup read from it)."""
    _err_console.print(Text.assemble(("error:", "bold red"), " ", str(err)), highlight=False)


def fail(err: BaseException, code: int = 2) -> NoReturn:
    """The one way a command gives up: the error in red, then exit `code` (2: a usage or config error)."""
    print_error(err)
    raise typer.Exit(code)


def print_json(obj) -> None:
    print(json.dumps(obj, indent=2))


@dataclass(frozen=True)
class ZenohFlags:
    """The connection flags of one command: they override the config's transport section (or `file`)."""

    mode: str | None = None
    connect: tuple[str, ...] = ()
    listen: tuple[str, ...] = ()
    file: str | None = None  # --zenoh-config: a JSON5 path or a shipped name (client, router)

    @classmethod
    def of(
        cls, mode: str | None, connect: list[str] | None, listen: list[str] | None, zenoh_config: str | None
    ) -> ZenohFlags:
        """From the parsed options (typer gives None for a repeatable option never given)."""
        return cls(mode, tuple(connect or ()), tuple(listen or ()), zenoh_config)

    def config(self, transport: TransportConfig, role: Literal["service", "node"]) -> zenoh.Config:
        """The zenoh.Config for a session; a bad mode or file raises ConfigError."""
        from replanner.transport.session import make_config

        return make_config(transport, role, self.mode, self.connect, self.listen, self.file)

    def args(self, *, listen: bool = True) -> list[str]:
        """The same flags on a child process's command line (without --listen for a second process: one port)."""
        out = ["-m", self.mode] if self.mode else []
        for e in self.connect:
            out += ["-e", e]
        for e in self.listen if listen else ():
            out += ["-l", e]
        if self.file:
            out += ["--zenoh-config", self.file]
        return out
