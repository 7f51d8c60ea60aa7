"""The ``ursa`` command: ``ursa up`` runs the stack; ``ursa eval ...`` evaluates a run;
``ursa export`` writes a run's policy as ONNX; ``ursa secrets`` writes a run's bus key and router
credentials.

One tyro command line over the dataclass of each subcommand: :class:`services.launcher.UpArgs`,
:data:`ursa.eval.cli.EvalCommand` (``ursa eval <command>``), :class:`ursa.export.ExportArgs` and
:class:`services.common.secrets.SecretsArgs`. What a command needs beyond its arguments (torch,
the envs) is imported once it runs, so that ``ursa --help`` stays quick.
"""

from __future__ import annotations

import dataclasses
import sys
from dataclasses import dataclass
from typing import Annotated, Union

import tyro

from services.common.secrets import SecretsArgs, secrets_command
from services.launcher import UpArgs, up
from ursa.eval.cli import DESCRIPTION as EVAL_DESCRIPTION
from ursa.eval.cli import EvalCommand, execute
from ursa.export import ExportArgs, export_command


@dataclass(frozen=True)
class EvalCli:
    """``ursa eval <command>``: one of the commands of :mod:`ursa.eval.cli`."""

    command: Annotated[EvalCommand, tyro.conf.arg(name="")]


Command = Union[  # noqa: UP007 - subcommands are Annotated members of a Union
    Annotated[UpArgs, tyro.conf.subcommand("up")],
    Annotated[EvalCli, tyro.conf.subcommand("eval", description=EVAL_DESCRIPTION)],
    Annotated[ExportArgs, tyro.conf.subcommand("export")],
    Annotated[SecretsArgs, tyro.conf.subcommand("secrets")],
]
"""The subcommands of ``ursa``, for ``tyro.cli`` (their help: the dataclasses' docstrings)."""


def parse(argv: list[str]) -> UpArgs | EvalCli | ExportArgs | SecretsArgs:
    """The command of a command line. ``ursa up [...] -- ARGS`` passes ARGS through to every
    service (``UpArgs.extra``): tyro would take a service flag such as
    ``--core.learner.imag-starts`` for one of ``up``'s own."""
    passthrough: list[str] = []
    if argv[:1] == ["up"] and "--" in argv:
        cut = argv.index("--")
        argv, passthrough = argv[:cut], argv[cut + 1 :]
    args: UpArgs | EvalCli | ExportArgs | SecretsArgs = tyro.cli(
        Command,
        args=argv,
        prog="ursa",
        description="URSA: the stack, its evaluation and its policy outside it.",
    )
    if isinstance(args, UpArgs) and passthrough:
        args = dataclasses.replace(args, extra=(*args.extra, *passthrough))
    return args


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``ursa`` (``sys.argv[1:]`` by default); returns the exit status (2 and a
    message on a bad command line)."""
    args = parse(list(sys.argv[1:] if argv is None else argv))
    if isinstance(args, UpArgs):
        return up(args)
    if isinstance(args, EvalCli):
        return execute(args.command)
    if isinstance(args, ExportArgs):
        return export_command(args)
    return secrets_command(args)


if __name__ == "__main__":
    raise SystemExit(main())
