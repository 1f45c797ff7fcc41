"""Compiled code loaded from numba's on-disk cache is the code that was compiled for it.

Numba names compiled functions by a per-process counter; cached libraries written
by two processes could define the same symbol with different bodies, and a process
loading both ran one body for the other (lie_factors.kernels.cache). These tests
write caches in separate processes and load them together in a third.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest
from numba.core.bytecode import FunctionIdentity

from lie_factors.kernels import cache as kernel_cache
from lie_factors.kernels import jit  # noqa: F401  (installs the cache policy, as every kernel module does)
from lie_factors import so3

# A factory builds functions with one qualified name and different bodies, as numba's
# quicksort does for np.sort and np.argsort (the functions behind the collision first seen).
FACTORY = """
from numba import njit

def scaled_by(k):
    @njit
    def scale(x):
        # long enough that its callers call it by its symbol rather than inlining it
        out = x.copy()
        for i in range(out.size):
            for _ in range(k):
                out[i] = out[i] * 2.0 if i % 2 == 0 else out[i] * 2.0 + 0.0
        return out
    return scale
"""

USER = """
import numpy as np
from numba import njit
import factory

scale = factory.scaled_by({k})

@njit(cache=True)
def run(x):
    a = np.full(4, float(x))
    return scale(a)[0] + scale(a)[1] + scale(a)[2] + scale(a)[3]
"""

# Each writer imports lie_factors first, as a user's process does, then compiles one module:
# both run the same code up to the compilation, so numba's counters (without the policy) agree.
WRITE = "import lie_factors.kernels.jit, {mod}; print({mod}.run(1))"
LOAD = "import lie_factors.kernels.jit, quadruple, octuple; print(quadruple.run(5), octuple.run(5))"


def _python(code: str, cwd, env) -> str:
    out = subprocess.run([sys.executable, "-c", code], cwd=cwd, env=env, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout.strip()


def test_functions_of_one_name_cached_by_two_processes_keep_their_own_bodies(tmp_path):
    (tmp_path / "factory.py").write_text(FACTORY)
    (tmp_path / "quadruple.py").write_text(USER.format(k=2))  # scale() multiplies by 2^k
    (tmp_path / "octuple.py").write_text(USER.format(k=3))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), *sys.path]))
    env.pop("NUMBA_CACHE_DIR", None)
    assert _python(WRITE.format(mod="quadruple"), tmp_path, env) == "16.0"
    assert _python(WRITE.format(mod="octuple"), tmp_path, env) == "32.0"
    cached = sorted(p.name for p in (tmp_path / "__pycache__").glob("*.nbc"))
    assert [name.split("-")[0] for name in cached] == ["octuple.run", "quadruple.run"]
    # both libraries come from the cache, each with its own copy of its scale()
    assert _python(LOAD, tmp_path, env) == "80.0 160.0"


def test_two_processes_number_their_functions_apart():
    code = "import lie_factors.kernels.jit; from numba.core.bytecode import FunctionIdentity as F; print(next(F._unique_ids))"
    env = dict(os.environ)
    first, second = (int(_python(code, None, env)) for _ in range(2))
    assert first != second
    # far apart: a process compiles thousands of functions, not 2^40
    assert abs(first - second) > 2 ** 40


def test_the_counter_stays_above_every_uid_already_drawn():
    before = next(FunctionIdentity._unique_ids)
    kernel_cache.install()  # idempotent: the counter is kept, not restarted
    after = next(FunctionIdentity._unique_ids)
    assert after == before + 1


def test_package_kernels_are_keyed_by_the_whole_package():
    impl = so3._exp._cache._impl
    assert isinstance(impl.locator, kernel_cache.PackageLocator)
    assert so3._exp._cache._cache_file._source_stamp == kernel_cache.package_digest()
    # where numba itself would have cached it
    assert impl.locator.get_cache_path() == os.path.join(os.path.dirname(so3.__file__), "__pycache__") \
        or os.environ.get("NUMBA_CACHE_DIR")


def test_a_function_outside_the_package_keeps_numbas_own_key(tmp_path):
    assert kernel_cache.PackageLocator.from_function(test_a_function_outside_the_package_keeps_numbas_own_key,
                                                     __file__) is None


def test_the_digest_covers_every_source_file_and_the_compiler(tmp_path, monkeypatch):
    import shutil
    copy = tmp_path / "lie_factors"
    shutil.copytree(kernel_cache.PACKAGE, copy, ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(kernel_cache, "PACKAGE", copy)
    digests = []
    for edit in (None, "app/cli.py", "incremental/elimination.py"):
        kernel_cache.package_digest.cache_clear()
        if edit:
            with open(copy / edit, "a") as f:
                f.write("\n# edited\n")
        digests.append(kernel_cache.package_digest())
    monkeypatch.setattr(kernel_cache.numba, "__version__", "0.0.0")
    kernel_cache.package_digest.cache_clear()
    digests.append(kernel_cache.package_digest())
    kernel_cache.package_digest.cache_clear()
    assert len(set(digests)) == len(digests)


@pytest.mark.slow
def test_the_batch_and_incremental_kernels_cached_apart_run_together(tmp_path):
    """The functions of the first crash: the batch solver's leave-out statistic sorts with np.sort
    and the smoother's pool compaction orders with np.argsort; each package's cache written by its
    own process, then both loaded by a third that compacts pools."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    batch = textwrap.dedent("""
        import numpy as np
        from lie_factors.robust import leave_out as lo
        i8 = lambda n: np.zeros(n, dtype=np.int64)
        f8 = lambda *s: np.zeros(s)
        lo._group_gram(lo.UnitLower(i8(2), i8(1), f8(1), f8(1)), i8(1), i8(0), i8(0), f8(0, 1, 1), f8(0, 1, 1), i8(1), i8(0), i8(1), f8(0))
        print(sum(lo._group_gram.stats.cache_misses.values()))
    """)
    compact = textwrap.dedent("""
        import numpy as np
        from lie_factors.robust import leave_out as lo
        from lie_factors.incremental import storage
        from lie_factors.incremental.structures import Pools, Tree
        if {load_batch}:
            i8 = lambda n: np.zeros(n, dtype=np.int64)
            f8 = lambda *s: np.zeros(s)
            lo._group_gram(lo.UnitLower(i8(2), i8(1), f8(1), f8(1)), i8(1), i8(0), i8(0), f8(0, 1, 1), f8(0, 1, 1), i8(1), i8(0), i8(1), f8(0))
        dim = np.ones(3, dtype=np.int64)
        sep_start, sep_len, sep_dim = np.array([8, 2, -1]), np.array([1, 1, 0]), np.array([1, 1, 0])
        cond, ustart = np.array([20, 4, 12]), np.full(3, -1)
        ipool, fpool = np.arange(10) * 100, np.arange(30.0)
        zeros = np.zeros(3, dtype=np.int64)
        tree = Tree(dim, zeros, zeros, zeros, zeros, zeros, zeros, sep_start, sep_len, sep_dim, cond, ustart,
                    np.full(1, -1))
        tops = storage.compact_pools(3, tree, Pools(ipool, fpool))
        print(tops, sep_start.tolist(), cond.tolist(), ipool[:2].tolist(), fpool[:3].tolist())
    """)
    assert _python(batch, tmp_path, env) == "1"  # compiled here, written to the cache
    expected = "(2, 8) [1, 0, -1] [5, 0, 3] [200, 800] [4.0, 5.0, 6.0]"
    assert _python(compact.format(load_batch=False), tmp_path, env) == expected
    assert _python(compact.format(load_batch=True), tmp_path, env) == expected
