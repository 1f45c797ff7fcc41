"""An optional extra that is not installed is one line naming the package to install."""

import subprocess

import lie_factors as lf


def one_line_refusal(what: str, call, *words: str) -> None:
    """``call()`` must raise an InputError of one line holding every one of ``words``."""
    try:
        call()
    except lf.InputError as exc:
        message = str(exc)
        assert all(w in message for w in words) and "\n" not in message, message
        print(f"{what}: {message}")
    else:
        raise SystemExit(f"{what}: ran")


pg = lf.read_g2o("data/intel.g2o")
one_line_refusal("pardiso without pypardiso", lambda: lf.optimize(pg, linear_solver="pardiso"), "pypardiso")

# The sweep without Dask (the extra sweep): one line naming the package, from Python and the command.
with open("sweep.toml", "w") as fh:
    fh.write('[graphs]\nintel = "data/intel.g2o"\n[methods.plain]\n')
one_line_refusal("sweep without dask", lambda: lf.sweep("sweep.toml", "sweep.csv"), "dask", "pip install")
p = subprocess.run(["lie-factors", "sweep", "sweep.toml", "--out", "sweep.csv"], capture_output=True, text=True)
assert p.returncode == 2 and p.stderr.count("\n") == 1 and "dask" in p.stderr, (p.returncode, p.stderr)

# A sweep's Parquet results without pyarrow (the extra parquet): one line naming it.
with open("results.parquet", "wb") as fh:
    fh.write(b"PAR1")
one_line_refusal("parquet without pyarrow", lambda: lf.sweep_summary("results.parquet"), "pyarrow")
