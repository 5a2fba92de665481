"""Build the API reference (HTML) from the docstrings with pdoc: ``python docs/build_api.py [OUT]``
(``make docs``; default OUT docs/api)."""

from __future__ import annotations

import sys
from pathlib import Path

# the public API (re-exported lazily by `import aerohrl`, which pdoc cannot follow) and the modules
# whose objects it takes or returns
MODULES = [
    "aerohrl.api",
    "aerohrl.errors",
    "aerohrl.task",
    "aerohrl.datagen.spec",
    "aerohrl.datagen.dataset",
    "aerohrl.datagen.exchange",
    "aerohrl.algorithms.config",
    "aerohrl.eval.harness",
    "aerohrl.envs.reach",
    "aerohrl.envs.maze",
]


def main(out: str | Path = Path(__file__).resolve().parent / "api") -> None:
    import pdoc

    pdoc.render.configure(docformat="google", footer_text="aerohrl", search=True)
    pdoc.pdoc(*MODULES, output_directory=Path(out))


if __name__ == "__main__":
    main(*sys.argv[1:2])
