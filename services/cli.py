"""The ``ursa`` command: ``ursa up`` runs the stack; ``ursa eval ...`` evaluates a run;
``ursa secrets`` writes a run's bus key and router credentials."""

from __future__ import annotations

import sys


def main(argv: list[str] | None = None) -> None:
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] in ("-h", "--help"):
        print(
            "usage: ursa {up,eval,export,secrets} ...\n\n  up       start the whole stack on "
            "this machine\n  eval     reproduce the paper's figures from a run directory\n"
            "  export   write a run's policy as ONNX with a JSON of its interface\n"
            "  secrets  write a run's bus key and router credentials (<run>/secrets)"
        )
        raise SystemExit(0 if args else 2)
    cmd, rest = args[0], args[1:]
    if cmd == "up":
        import tyro

        from services.launcher import UpArgs, up

        raise SystemExit(up(tyro.cli(UpArgs, args=rest)))
    if cmd == "secrets":
        from services.common.secrets import main as secrets_main

        raise SystemExit(secrets_main(rest))
    if cmd == "eval":
        from ursa.eval.cli import main as eval_main

        raise SystemExit(eval_main(rest))
    if cmd == "export":
        from ursa.export import main as export_main

        raise SystemExit(export_main(rest))
    print(f"unknown command {cmd!r}; try `ursa --help`", file=sys.stderr)
    raise SystemExit(2)


if __name__ == "__main__":
    main()
