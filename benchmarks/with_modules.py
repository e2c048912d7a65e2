"""Run a benchmark script with module switches set first, for A/B timings of code paths that are
module constants rather than Config fields.

    python benchmarks/with_modules.py physhand_mj.contact.objects.PSEUDO_NORMAL_TABLE=False -- \
        benchmarks/batch_hoi.py --device cuda --scenes bowl --worlds 1024

Each ``module.NAME=VALUE`` (VALUE a Python literal) is set after importing the module and before
the script runs (as ``__main__``, with the arguments after ``--``). It reaches code that reads the
module's attribute when it runs (``objects.PSEUDO_NORMAL_TABLE``), not a name copied elsewhere by
``from module import NAME``.
"""

from __future__ import annotations

import ast
import importlib
import os
import runpy
import sys

ENV = "PHYSHAND_WITH_MODULES"  # the switches set, for the scripts' records


def main() -> None:
    args = sys.argv[1:]
    if "--" not in args:
        raise SystemExit(__doc__)
    cut = args.index("--")
    if cut + 1 >= len(args):
        raise SystemExit("no script after --\n\n" + __doc__)
    for item in args[:cut]:
        target, eq, value = item.partition("=")
        module, _, name = target.rpartition(".")
        if not eq or not module:
            raise SystemExit(f"{item!r}: give module.NAME=VALUE, "
                             "e.g. physhand_mj.contact.objects.PSEUDO_NORMAL_TABLE=False")
        mod = importlib.import_module(module)
        if not hasattr(mod, name):
            raise SystemExit(f"{module} has no {name}")
        setattr(mod, name, ast.literal_eval(value))
    script, rest = args[cut + 1], args[cut + 2:]
    os.environ[ENV] = " ".join(args[:cut])  # what a script records as its command (batch_hoi.py) names them
    sys.argv = [script, *rest]
    runpy.run_path(script, run_name="__main__")


if __name__ == "__main__":
    main()
