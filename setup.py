"""The install's build step: compile the kernels of every command into numba's cache.

setuptools reads the project from ``pyproject.toml``; this file adds one thing to its
``build_py`` (which ``pip install -e .`` runs too): ``python -m lie_factors.app.warmup`` in pip's
build environment, from the source tree, so that a user's first command loads its kernels
instead of compiling them (docs/installing.md).  ``LIE_FACTORS_NO_WARMUP=1`` skips it.  A warm-up
that fails leaves the kernels to compile on first use: the install goes on.
"""

import os
import subprocess
import sys
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent


class BuildPyWithKernels(build_py):
    def run(self):
        super().run()
        if os.environ.get("LIE_FACTORS_NO_WARMUP"):
            return
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
        done = subprocess.run([sys.executable, "-m", "lie_factors.app.warmup"], cwd=ROOT, env=env,
                              capture_output=True, text=True)
        line = (done.stderr.strip().splitlines() or ["no output"])[-1]
        print(line if done.returncode == 0 else f"lie-factors: the kernels were not compiled at install ({line})",
              file=sys.stderr)


setup(cmdclass={"build_py": BuildPyWithKernels})
