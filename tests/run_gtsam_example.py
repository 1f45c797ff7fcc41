"""Run one of the Python examples shipped in the gtsam wheel, as GTSAM ships it or with our factors.

    python run_gtsam_example.py NAME original|swapped [ARG ...]

Run by tests/test_gtsam_examples.py in a fresh process, in an empty working
directory.  ``swapped`` changes only the example's import lines: ``import
gtsam`` becomes ``import lie_factors.dropin as gtsam`` and ``from gtsam import
...`` becomes ``from lie_factors.dropin import ...`` (``from gtsam.X import``
lines are left alone: nothing in GTSAM's submodules is replaced).

Around the example, identically in both modes: ``np.random`` seeded (several
examples draw unseeded noise), matplotlib on Agg with ``plt.show`` and
``plt.pause`` doing nothing (no display; ``pause`` would also sleep), ``argv``
set to ``ARG ...``.  After it, on stdout: the data of every line plotted
(examples that print nothing plot their estimates) and the contents of every
file the example wrote.  On stderr, last line: the JSON count of
lie_factors.factors' factors constructed, by class.

An example that is a module rather than a script (LandmarkLocalizationDataset)
is driven by the code in ``DRIVERS``.
"""

import json
import os
import re
import sys
from collections import Counter

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import gtsam  # noqa: E402

#: module-like examples: code run after the module body, in its namespace
DRIVERS = {
    "LandmarkLocalizationDataset": (
        "dataset = LandmarkLocalizationDataset(6)\n"
        "dataset.write_g2o('exact.g2o', dataset.exact_measurements())\n"
        "dataset.write_g2o('perturbed.g2o', dataset.perturbed_measurements())\n"
    ),
}

IMPORT = re.compile(r"(?m)^(\s*)import gtsam\s*$")
FROM_IMPORT = re.compile(r"(?m)^(\s*)from gtsam import ")


def swap_imports(source: str) -> tuple[str, int]:
    """``source`` with its gtsam import lines pointed at lie_factors.dropin, and how many were changed."""
    source, n1 = IMPORT.subn(r"\1import lie_factors.dropin as gtsam", source)
    source, n2 = FROM_IMPORT.subn(r"\1from lie_factors.dropin import ", source)
    return source, n1 + n2


def count_our_factors() -> Counter:
    """Count constructions of lie_factors.factors' classes (the count only; behaviour unchanged)."""
    from lie_factors import factors

    made: Counter = Counter()
    for base in (factors.BetweenFactor, factors.PriorFactor):
        init = base.__init__

        def counted(self, *args, _init=init, **kwargs):
            made[type(self).__name__] += 1
            _init(self, *args, **kwargs)

        base.__init__ = counted
    return made


def plotted_data() -> str:
    lines = []
    for num in plt.get_fignums():
        for ax in plt.figure(num).axes:
            for line in ax.get_lines():
                data = line.get_data_3d() if hasattr(line, "get_data_3d") else line.get_data()
                flat = np.concatenate([np.ravel(np.asarray(d, dtype=float)) for d in data])
                lines.append(f"figure {num} line: " + " ".join(repr(float(x)) for x in flat))
    return "\n".join(lines)


def main() -> None:
    name, mode, *args = sys.argv[1:]
    examples = os.path.join(os.path.dirname(gtsam.__file__), "examples")
    path = os.path.join(examples, name + ".py")
    with open(path) as fh:
        source = fh.read()
    made: Counter = Counter()
    if mode == "swapped":
        source, changed = swap_imports(source)
        if not changed:
            raise SystemExit(f"{name}: no gtsam import line to change")
        made = count_our_factors()
    elif mode != "original":
        raise SystemExit(f"mode must be original or swapped, not {mode!r}")

    plt.show = lambda *a, **k: None
    plt.pause = lambda *a, **k: None
    sys.path.insert(0, examples)  # examples import their siblings (PreintegrationExample, ...)
    sys.argv = [path, *args]
    np.random.seed(0)
    before = set(os.listdir("."))
    namespace = {"__name__": name if name in DRIVERS else "__main__", "__file__": path}
    exec(compile(source, path, "exec"), namespace)
    if name in DRIVERS:
        exec(DRIVERS[name], namespace)

    sys.stdout.flush()
    print("=== plotted data")
    print(plotted_data())
    for fname in sorted(set(os.listdir(".")) - before):
        print(f"=== file {fname}")
        with open(fname) as fh:
            print(fh.read())
    sys.stdout.flush()
    print(json.dumps(dict(made)), file=sys.stderr)


if __name__ == "__main__":
    main()
