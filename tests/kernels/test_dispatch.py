"""Group tags (lie_factors.kernels.dispatch): one specialization per group, nothing else compiled."""

from __future__ import annotations

import json
import os
import pickle
import shutil
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from numba import njit
from numba.core.errors import TypingError

from lie_factors.kernels import dispatch as _dispatch, registry
from lie_factors import factors, se2, se3, sim2, sim3, so3

GROUPS = [(_dispatch.SO3, so3, 3), (_dispatch.SE3, se3, 3), (_dispatch.SE2, se2, 2), (_dispatch.SIM2, sim2, 2),
          (_dispatch.SIM3, sim3, 3)]


@njit
def _constants(g):
    return _dispatch.dim(g), _dispatch.mat(g), _dispatch.rot_dim(g), _dispatch.corner(g)


@njit
def _exp_log(g, x, X, y):
    _dispatch.exp(g, x, X)
    _dispatch.log(g, X, y)


@njit
def _algebra(g, x, H, y, A, D):
    _dispatch.hat(g, x, H)
    _dispatch.vee(g, H, y)
    _dispatch.ad(g, x, A)
    _dispatch.dexp(g, x, D)


@pytest.mark.parametrize("tag, module, rot", GROUPS, ids=lambda v: getattr(v, "name", None))
def test_tag_reaches_every_core_of_its_group(tag, module, rot):
    x = np.linspace(0.1, 0.4, module.DIM)
    H, y = np.empty((module.MAT, module.MAT)), np.empty(module.DIM)
    A, D = np.empty((module.DIM, module.DIM)), np.empty((module.DIM, module.DIM))
    _algebra(tag, x, H, y, A, D)
    assert np.array_equal(H, module.hat(x)) and np.array_equal(y, x)
    assert np.array_equal(A, module.ad(x)) and np.array_equal(D, module.dexp(x))


@pytest.mark.parametrize("tag, module, rot", GROUPS, ids=lambda v: getattr(v, "name", None))
def test_tag_reaches_its_own_group(tag, module, rot):
    assert _constants(tag) == (module.DIM, module.MAT, rot, tag.corner)
    x = np.linspace(0.1, 0.4, module.DIM)
    X = np.empty((module.MAT, module.MAT))
    y = np.empty(module.DIM)
    _exp_log(tag, x, X, y)
    np.testing.assert_allclose(X, module.exp(x), rtol=0, atol=1e-15)
    np.testing.assert_allclose(y, x, rtol=0, atol=1e-14)


def test_the_tags_are_the_registry_entries():
    assert [_dispatch.SO3, _dispatch.SE3, _dispatch.SE2, _dispatch.SIM2, _dispatch.SIM3] == list(registry.GROUPS.values())
    assert set(_dispatch.GROUPS) == set(registry.GROUPS) | set(registry.QUATERNIONS)


def test_tags_are_distinct_types_and_pickle_by_name():
    types = {tag._numba_type_ for tag, _, _ in GROUPS}
    assert len(types) == len(GROUPS)
    for tag, _, _ in GROUPS:
        assert pickle.loads(pickle.dumps(tag)) is tag
        assert pickle.loads(pickle.dumps(tag._numba_type_)) == tag._numba_type_


def test_integer_group_id_is_a_typing_error():
    with pytest.raises(TypingError, match="group tag"):
        _constants(1)


def test_registering_a_group_twice_is_refused():
    with pytest.raises(ValueError, match="already registered"):
        _dispatch.register(registry.SE3)


def test_factor_specs_use_the_registered_tags():
    assert {spec.group for spec in factors.GROUPS.values()} <= {t for t, _, _ in GROUPS}


_SE3_ONLY = textwrap.dedent(
    """
    import json
    import numpy as np
    import gtsam
    from lie_factors import factors, se2, sim2, sim3, se3
    import lie_factors as lf

    noise = gtsam.noiseModel.Isotropic.Sigma(6, 0.1)
    a = gtsam.Pose3(gtsam.Rot3.Ypr(0.1, 0.2, 0.3), np.array([1.0, 2.0, 3.0]))
    graph = gtsam.NonlinearFactorGraph()
    graph.add(factors.PriorFactorPose3(0, gtsam.Pose3(), noise))
    graph.add(factors.BetweenFactorPose3(0, 1, a, noise))
    values = gtsam.Values()
    values.insert(0, gtsam.Pose3())
    values.insert(1, a.compose(gtsam.Pose3.Expmap(np.full(6, 0.05))))
    graph.linearize(values)
    lf.optimize(graph, values, max_iterations=3, linear_solver="cholmod")  # the general loop: its kernels
    def own_compiled(m):  # kernels defined in m (not imported into it) that were compiled
        return sorted(name for name, f in vars(m).items()
                      if getattr(f, "signatures", None) and f.py_func.__module__ == m.__name__)

    compiled = {m.__name__.split(".")[-1]: own_compiled(m) for m in (se2, sim2, sim3, se3)}
    print(json.dumps(compiled))
    """
)


@pytest.mark.slow
def test_se3_graph_compiles_no_other_group(tmp_path):
    """Fresh numba cache: factors + batch solver on an SE(3) graph compile SE(3) cores only."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    out = subprocess.run([sys.executable, "-c", _SE3_ONLY], env=env, capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr
    compiled = json.loads(out.stdout.strip().splitlines()[-1])
    assert compiled["se2"] == [] and compiled["sim2"] == [] and compiled["sim3"] == [], compiled
    assert {"_inverse", "_compose", "_log", "_dlog", "_Ad", "_exp"} <= set(compiled["se3"]), compiled


_EXP_ONE_AND_BATCH = "import numpy as np; from lie_factors import so3; x = np.full(3, 0.1); print(so3.exp(x)[0, 0], so3.exp(x[None])[0, 0, 0])"


@pytest.mark.slow
def test_editing_a_core_recompiles_the_generic_kernels(tmp_path):
    """Numba caches a generic kernel under its own file, keyed (lie_factors.kernels.cache) by the
    whole package's sources, so after a core is edited the public functions (and the factors) run
    the new code, not the specializations cached before (a copy of the package, its own cache)."""
    package = tmp_path / "lie_factors"
    shutil.copytree(os.path.dirname(factors.__file__), package,
                    ignore=shutil.ignore_patterns("__pycache__", "app", "g2o", "batch", "optimizers", "initialization"))
    env = dict(os.environ, PYTHONPATH=str(tmp_path))
    env.pop("NUMBA_CACHE_DIR", None)

    def run():
        out = subprocess.run([sys.executable, "-c", _EXP_ONE_AND_BATCH], env=env, cwd=tmp_path,
                             capture_output=True, text=True, timeout=600)
        assert out.returncode == 0, out.stderr
        return [float(v) for v in out.stdout.split()]

    before = run()
    assert before[0] == before[1] != 42.0
    so3_file = package / "so3.py"
    source = so3_file.read_text()
    edited = source.replace("    _rodrigues(x[0], x[1], x[2], a_theta(th), b_theta(th), out)\n",
                            "    _rodrigues(x[0], x[1], x[2], a_theta(th), b_theta(th), out)\n    out[0, 0] = 42.0\n", 1)
    assert edited != source
    so3_file.write_text(edited)
    assert run() == [42.0, 42.0]
    so3_file.write_text(source)
    assert run() == before
