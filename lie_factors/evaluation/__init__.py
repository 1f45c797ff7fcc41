"""Trajectories in and out (TUM, KITTI) and their errors against a reference (ATE, RPE), as evo computes them.

:mod:`~lie_factors.evaluation.trajectory` reads and writes the files;
:mod:`~lie_factors.evaluation.metrics` associates, aligns and measures.  The front
door's ``lf.read_trajectory``, ``lf.write_trajectory`` and ``lf.evaluate`` take
results, pose graphs and files as well (``docs/evaluation.md``).
"""
