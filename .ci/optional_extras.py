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
