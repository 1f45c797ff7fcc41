"""Run Python examples shipped in the gtsam wheel, as GTSAM ships them or with our factors.

    python run_gtsam_example.py original|swapped|assigned OUTDIR CASES_JSON

``CASES_JSON``: a list of ``[index, name, [arg, ...]]``.  Run by
tests/gtsam/test_gtsam_examples.py: one process runs the cases given, in order,
each in its own empty working directory ``OUTDIR/<index>`` (one process
rather than one per case: starting Python, gtsam, matplotlib and our kernels
is most of the time of an example).  ``swapped`` changes only the
example's import lines; ``assigned`` runs it as shipped with our names
assigned into ``gtsam``'s namespace first (``gtsam_swap.py`` says how).

Around each example, identically in every mode: ``np.random`` seeded (several
examples draw unseeded noise) and numpy's print options reset, matplotlib on
Agg with ``plt.show`` and ``plt.pause`` doing nothing (no display; ``pause``
would also sleep) and every figure closed, ``sys.argv`` set to the case's
arguments.  Written to ``OUTDIR/<index>/``:

* ``stdout``: everything the example printed, Python's and C++'s (file
  descriptor 1, unbuffered, so in program order), then the data of every line
  it plotted (examples that print nothing plot their estimates), then the
  contents of every file it wrote;
* ``made.json``: how many of lie_factors.factors' factors it constructed, by class;
* ``error``: the traceback, if it raised;
* ``seconds``: its wall time.

An example that is a module rather than a script (LandmarkLocalizationDataset)
is driven by the code in ``DRIVERS``.
"""

import ctypes
import json
import os
import sys
import time
import traceback
from collections import Counter

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import gtsam  # noqa: E402
import gtsam_swap  # noqa: E402

#: module-like examples: code run after the module body, in its namespace
DRIVERS = {
    "LandmarkLocalizationDataset": (
        "dataset = LandmarkLocalizationDataset(6)\n"
        "dataset.write_g2o('exact.g2o', dataset.exact_measurements())\n"
        "dataset.write_g2o('perturbed.g2o', dataset.perturbed_measurements())\n"
    ),
}

EXAMPLES = os.path.join(os.path.dirname(gtsam.__file__), "examples")

_libc = ctypes.CDLL(None)


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


def _flush() -> None:
    sys.stdout.flush()
    _libc.fflush(None)  # C stdio (GTSAM's std::cout writes through it)


def run_case(name: str, args: list, mode: str, made: Counter) -> None:
    path = os.path.join(EXAMPLES, name + ".py")
    with open(path) as fh:
        source = fh.read()
    source = gtsam_swap.prepare(mode, source, name)
    plt.close("all")
    np.set_printoptions(**_PRINT_OPTIONS)
    sys.argv = [path, *args]
    np.random.seed(0)
    made.clear()
    before = set(os.listdir("."))
    namespace = {"__name__": name if name in DRIVERS else "__main__", "__file__": path}
    exec(compile(source, path, "exec"), namespace)
    if name in DRIVERS:
        exec(DRIVERS[name], namespace)
    _flush()
    print("=== plotted data")
    print(plotted_data())
    for fname in sorted(set(os.listdir(".")) - before):
        print(f"=== file {fname}")
        with open(fname) as fh:
            print(fh.read())


_PRINT_OPTIONS = np.get_printoptions()


def main() -> None:
    mode, outdir, cases = sys.argv[1], os.path.abspath(sys.argv[2]), json.loads(sys.argv[3])
    gtsam_swap.start(mode)
    made = count_our_factors() if mode != "original" else Counter()
    plt.show = lambda *a, **k: None
    plt.pause = lambda *a, **k: None
    sys.path.insert(0, EXAMPLES)  # examples import their siblings (PreintegrationExample, ...)
    # C stdio unbuffered, so C++ and Python output interleave in program order.
    _libc.setvbuf(ctypes.c_void_p.in_dll(_libc, "stdout"), None, 2, 0)  # 2 = _IONBF
    saved_fd = os.dup(1)
    for index, name, args in cases:
        where = os.path.join(outdir, str(index))
        os.makedirs(where)
        os.chdir(where)
        _flush()
        start = time.perf_counter()
        with open("stdout", "w") as out:
            os.dup2(out.fileno(), 1)
            try:
                run_case(name, args, mode, made)
            except BaseException:  # noqa: BLE001 - recorded for the test, then the next case
                with open("error", "w") as fh:
                    fh.write(traceback.format_exc())
            finally:
                _flush()
                os.dup2(saved_fd, 1)
        with open("made.json", "w") as fh:
            json.dump(dict(made), fh)
        with open("seconds", "w") as fh:
            fh.write(f"{time.perf_counter() - start:.2f}\n")


if __name__ == "__main__":
    main()
