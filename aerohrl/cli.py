"""The umbrella command: ``aerohrl datagen|train|runs|ipp|eval ...``.

Each stage also has its own entry point (``datagen``); the umbrella forwards the rest
of the command line to it. (``eval`` alone is a shell builtin, which is why the
evaluation harness will be reached as ``aerohrl eval``.)
"""

from __future__ import annotations

import sys

USAGE = """usage: aerohrl COMMAND [ARGS...]

commands:
  datagen   expert quadrotor datasets (build, info, validate, export, push, plot)
  train     offline goal-conditioned RL on a dataset (gcsl, td3bc, td3awbc, cql; OGBench agents gciql, crl, qrl, hiql)
  runs      inspect training runs (runs show RUN)
  ipp       informative path planning on motion primitives (lattice, bench, ...)
  eval      evaluate runs in the simulator (reach-desired, reach-intermediate, ood + planner; table, plot)
  bench     the benchmark: mazes and free space, dataset families, frozen tasks (bench suite: the leaderboard)
  export-policy  a run's policy as TorchScript or ONNX for onboard use
  sweep     a grid of runs (algorithms x seeds x datasets x overrides) as Ray tasks, evaluated, seed-aggregated tables

Every command takes, where they mean something, the same flags: -o/--out PATH (where
results go), --quiet (no progress bars), --threads N, --seed N, --device DEV.
`aerohrl COMMAND --help` for each command's options."""


def _datagen(argv):
    from aerohrl.datagen.cli import main

    return main(argv)


def _train(argv):
    from aerohrl.algorithms.cli import main

    return main(argv)


def _runs(argv):
    from aerohrl.runs import main

    return main(argv)


def _ipp(argv):
    from aerohrl.ipp.cli import main

    return main(argv)


def _eval(argv):
    from aerohrl.eval.cli import main

    return main(argv)


def _bench(argv):
    from aerohrl.benchmark import main

    return main(argv)


def _sweep(argv):
    from aerohrl.sweep import main

    return main(argv)


def _export_policy(argv):
    from aerohrl.algorithms.cli import export_main

    return export_main(argv)


COMMANDS = {
    "datagen": _datagen,
    "train": _train,
    "runs": _runs,
    "ipp": _ipp,
    "eval": _eval,
    "sweep": _sweep,
    "bench": _bench,
    "export-policy": _export_policy,
}


def main(argv: list[str] | None = None) -> int:
    """The ``aerohrl`` command: dispatch ``argv[0]`` to its subcommand; returns the exit code."""
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help"):
        print(USAGE)
        return 0 if argv else 2
    if argv[0] == "--version":
        from aerohrl import __version__

        print(f"aerohrl {__version__}")
        return 0
    cmd = COMMANDS.get(argv[0])
    if cmd is None:
        print(f"aerohrl: error: unknown command {argv[0]!r} (choose from {', '.join(COMMANDS)})", file=sys.stderr)
        return 2
    try:
        return cmd(argv[1:])
    except ModuleNotFoundError as e:  # a stage whose extra is not installed (argument parsing imports it too)
        from aerohrl.errors import EXTRAS

        extra = EXTRAS.get((e.name or "").split(".")[0])
        if extra is None:
            raise
        print(
            f"aerohrl {argv[0]}: error: this needs {e.name}, which is not installed: pip install 'aerohrl[{extra}]'",
            file=sys.stderr,
        )
        return 2


if __name__ == "__main__":
    sys.exit(main())
