"""An optional extra that is not installed is one line naming the package to install."""

import lie_factors as lf

pg = lf.read_g2o("data/intel.g2o")
try:
    lf.optimize(pg, linear_solver="pardiso")
except lf.InputError as exc:
    message = str(exc)
    assert "pypardiso" in message and "\n" not in message, message
    print(f"pardiso without pypardiso: {message}")
else:
    raise SystemExit("linear_solver='pardiso' ran without pypardiso installed")

# The sweep without Dask (the extra sweep): one line naming the package, from Python and the command.
import subprocess  # noqa: E402
import sys  # noqa: E402

with open("sweep.toml", "w") as fh:
    fh.write('[graphs]\nintel = "data/intel.g2o"\n[methods.plain]\n')
try:
    lf.sweep("sweep.toml", "sweep.csv")
except lf.InputError as exc:
    message = str(exc)
    assert "dask" in message and "pip install" in message and "\n" not in message, message
    print(f"sweep without dask: {message}")
else:
    raise SystemExit("lf.sweep ran without dask installed")
p = subprocess.run(["lie-factors", "sweep", "sweep.toml", "--out", "sweep.csv"], capture_output=True, text=True)
assert p.returncode == 2 and p.stderr.count("\n") == 1 and "dask" in p.stderr, (p.returncode, p.stderr)

# A sweep's Parquet results without pyarrow (the extra parquet): one line naming it.
with open("results.parquet", "wb") as fh:
    fh.write(b"PAR1")
try:
    lf.sweep_summary("results.parquet")
except lf.InputError as exc:
    message = str(exc)
    assert "pyarrow" in message and "\n" not in message, message
    print(f"parquet without pyarrow: {message}")
else:
    raise SystemExit("a .parquet results file was read without pyarrow installed")
