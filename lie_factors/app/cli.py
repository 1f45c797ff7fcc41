"""``lie-factors``: command-line entry point.

Subcommands are registered in :data:`SUBCOMMANDS` (name → (help,
add_arguments, run)).  Optional ones live in their own module, listed in
:data:`OPTIONAL_SUBCOMMANDS`, and are offered only if that module exists.  Such
a module defines ``main(...) -> int | None`` and either

- ``add_arguments(parser)``: then ``main(args)`` gets our parsed
  ``argparse.Namespace``; or
- nothing else: then ``main(argv)`` gets the list of arguments after the
  subcommand name and parses them itself (``lie_factors.app.crosscheck`` does).

User errors (bad file, unwritable output, unknown backend, ...) print ONE line
``lie-factors: error: ...`` on stderr and exit with status 2, never a traceback.
With ``--json`` the last line of stdout is one JSON object.
"""

from __future__ import annotations

import argparse
import faulthandler
import gc
import importlib
import importlib.util
import json
import os
import sys
from typing import Callable

PROG = "lie-factors"
EXIT_USAGE = 2


# --------------------------------------------------------------------------- #
# helpers
# --------------------------------------------------------------------------- #

class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is ONE line on stderr (``lie-factors: error: ...``), exit 2."""

    def error(self, message):
        print(f"{PROG}: error: {message} (see '{self.prog} --help')", file=sys.stderr)
        sys.exit(EXIT_USAGE)


def _iterations(args):
    """:class:`lie_factors.Events` printing each iteration on stderr (none with --quiet)."""
    from lie_factors.events import Events
    from lie_factors.lm import format_iteration

    class Iterations(Events):
        def iteration(self, info):
            if not args.quiet:
                print(format_iteration(info), file=sys.stderr, flush=True)

    return Iterations()


def _say(args, text: str) -> None:
    """Human-readable stdout line (suppressed by --quiet; errors are never suppressed)."""
    if not args.quiet:
        print(text, flush=True)


def _emit_json(record: dict) -> None:
    # Last stdout line, one object: scripts can do `tail -n1 | jq`.
    print(json.dumps(record, sort_keys=False), flush=True)


#: Limits of the numeric options: beyond them a run would not finish in any useful
#: time (the demo's graph grows with --poses) or the value does not fit GTSAM's
#: iteration counter; such values are refused with one line instead.
MAX_DEMO_POSES = 100_000
MAX_ITERATIONS = 1_000_000
MAX_SEED = 2**63 - 1


def _bounded_int(option: str, low: int, high: int) -> Callable[[str], int]:
    """argparse type: an integer in [low, high], else argparse's one-line usage error (exit 2)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"must be from {low} to {high}, got {value}")
        return value

    parse.__name__ = option  # argparse names the type in some messages
    return parse


#: lie_factors.backends.BACKENDS, spelled out so that building the parser does not import GTSAM
#: (a test checks they agree); the first is the default.
BACKENDS = ("batch", "dropin", "native")
_BACKEND_HELP = ("batch = lie_factors factors in the vectorized solver; dropin = lie_factors factors in "
                 "lie_factors.optimizers' drop-in of GTSAM's LM; native = GTSAM's own factors, the reference")


# --------------------------------------------------------------------------- #
# posegraph
# --------------------------------------------------------------------------- #

#: lie_factors.initialization.METHODS, spelled out so that building the parser
#: does not import GTSAM (a test checks they agree).
INIT_METHODS = ("auto", "chordal", "lago", "spanning-tree", "odometry", "file")


def _add_posegraph(p: argparse.ArgumentParser) -> None:
    p.add_argument("dataset", metavar="DATASET",
                   help="g2o file (2-D VERTEX_SE2/EDGE_SE2, 3-D VERTEX_SE3:QUAT/EDGE_SE3:QUAT, "
                        "EDGE3, or Sim(3) VERTEX_SIM3:EXPMAP/EDGE_SIM3:EXPMAP), or the name of a "
                        "file shipped with GTSAM, e.g. sphere2500.txt")
    p.add_argument("--backend", default=BACKENDS[0], metavar="NAME",
                   help=f"factor implementation: {' | '.join(BACKENDS)} (default: {BACKENDS[0]}; {_BACKEND_HELP})")
    p.add_argument("--max-iterations", type=_bounded_int("--max-iterations", 0, MAX_ITERATIONS),
                   default=100, metavar="K",
                   help="Levenberg-Marquardt iteration limit (default: 100)")
    p.add_argument("--init", default="auto", choices=INIT_METHODS,
                   help="where LM starts: chordal = GTSAM's chordal relaxation (InitializePose3), "
                        "lago = GTSAM's LAGO (2-D, diagonal noise only), spanning-tree = "
                        "measurements composed along a BFS tree, odometry = the edges between "
                        "consecutive poses composed from the prior (dead reckoning), file = the "
                        "file's vertices; "
                        "auto (default) = chordal in 3-D, lago then chordal in 2-D, then file, "
                        "then spanning-tree: the first that applies; with --gnc or --robust, auto "
                        "uses the odometry edges and the prior only (their measurements composed; "
                        "the loop closures, possibly false, are left out), then file")
    p.add_argument("--robust", metavar="LOSS[:K]",
                   help="robust loss on the loop closures (edges between non-consecutive poses): "
                        "huber | cauchy | tukey | gm | dcs, optionally with its parameter, e.g. huber:1.345")
    p.add_argument("--robust-all", action="store_true",
                   help="apply the --robust loss to every edge, odometry included")
    p.add_argument("--gnc", metavar="{tls,gm}",
                   help="graduated non-convexity (GTSAM's GncOptimizer semantics) with truncated "
                        "least squares or Geman-McClure; odometry edges are known inliers; "
                        "the JSON gains 'outliers' (rejected edges, 0-based file order); the loop "
                        "closures first pass a consistency stage (odometry gate, pairwise consistency) "
                        "and a final chi-square check after, and 'rejected_by' names the stage that "
                        "rejected each edge (gate, clique, gnc, final); with --incremental (tls only), "
                        "each loop closure is tested as it arrives and again as the map grows "
                        "(rejected_by: online)")
    p.add_argument("--no-consistency", action="store_true",
                   help="with --gnc: skip the consistency stage and the final check (plain GNC, as "
                        "GTSAM's GncOptimizer)")
    p.add_argument("--incremental", action="store_true",
                   help="replay the file online instead (poses in id order, one per update; batch = "
                        "the incremental smoother lie_factors.incremental.Smoother on arrays, dropin = "
                        "our factors in lie_factors.optimizers.ISAM2, native = GTSAM's factors in "
                        "gtsam.ISAM2); the JSON adds incremental, updates, update_seconds, update_p50, "
                        "update_p99, relinearizations, reorderings")
    p.add_argument("--relinearize-threshold", type=_positive_float, default=0.1, metavar="T",
                   help="with --incremental: ISAM2's relinearizeThreshold (default: 0.1)")
    p.add_argument("--relinearize-skip", type=_bounded_int("--relinearize-skip", 1, MAX_ITERATIONS),
                   default=10, metavar="N",
                   help="with --incremental: ISAM2's relinearizeSkip (default: 10)")
    p.add_argument("--output", metavar="FILE",
                   help="write the optimized graph: g2o, or, by the extension .tum or .kitti, its trajectory "
                        "(TUM: stamp = pose id; 2-D poses as planar 3-D ones)")
    p.add_argument("--groundtruth", metavar="FILE",
                   help="a ground-truth trajectory (TUM or KITTI, or a g2o file's vertices): report the ATE "
                        "(SE(3)-aligned) of the start and of the optimum; the JSON gains ate_initial and ate")
    p.add_argument("--covariances", metavar="FILE.npz",
                   help="write every pose's marginal covariance (keys, covariances (n, d, d) in GTSAM's tangent "
                        "order, group) as NumPy .npz; with --plot, 2-D poses get their 95%% ellipses")
    p.add_argument("--plot", metavar="FILE.png", help="plot initial and optimized trajectories")
    p.add_argument("--json", action="store_true",
                   help="print a JSON summary as the last line of stdout")
    p.add_argument("--quiet", action="store_true", help="no progress and no human-readable report")


def _positive_float(text: str) -> float:
    """argparse type: a finite number > 0, else argparse's one-line usage error (exit 2)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (value > 0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return value


def _run_posegraph(args) -> int:
    """``lie-factors posegraph``: :mod:`lie_factors.app.posegraph` on the parsed ``args``."""
    import time

    t = time.perf_counter()
    from lie_factors.app import posegraph

    return posegraph.run(args, time.perf_counter() - t, t)


# --------------------------------------------------------------------------- #
# demo
# --------------------------------------------------------------------------- #

#: --scenario → (default --poses, what it is)
DEMO_SCENARIOS = {
    "se3": (300, "SE(3) odometry chain with loop closures, our factors (default)"),
    "sim3": (150, "monocular scale drift: a Sim(3) pose graph, our factors beside GTSAM's native ones"),
}


def _add_demo(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", default="se3", choices=list(DEMO_SCENARIOS),
                   help="; ".join(f"{k}: {v[1]}" for k, v in DEMO_SCENARIOS.items()))
    p.add_argument("--poses", type=_bounded_int("--poses", 2, MAX_DEMO_POSES), default=None, metavar="N",
                   help="number of poses (default: "
                        + ", ".join(f"{v[0]} for {k}" for k, v in DEMO_SCENARIOS.items())
                        + f"; from 2 to {MAX_DEMO_POSES})")
    p.add_argument("--seed", type=_bounded_int("--seed", 0, MAX_SEED), default=0, metavar="S",
                   help="random seed, a non-negative integer (default: 0)")
    p.add_argument("--output", default="lie-factors-demo", metavar="DIR",
                   help="directory for trajectory.png and optimized.g2o "
                        "(default: ./lie-factors-demo, created if missing)")
    p.add_argument("--backend", default=BACKENDS[0], metavar="NAME",
                   help=f"factor implementation: {' | '.join(BACKENDS)} (default: {BACKENDS[0]}; {_BACKEND_HELP}; "
                        "sim3 runs native beside it anyway)")
    p.add_argument("--max-iterations", type=_bounded_int("--max-iterations", 0, MAX_ITERATIONS),
                   default=100, metavar="K",
                   help="Levenberg-Marquardt iteration limit (default: 100)")
    p.add_argument("--json", action="store_true",
                   help="print a JSON summary as the last line of stdout")
    p.add_argument("--quiet", action="store_true", help="no progress and no human-readable report")


def _demo_files(args) -> tuple[str, str]:
    """The demo's (trajectory.png, optimized.g2o) in ``--output``, the directory created if missing,
    the g2o path checked writable."""
    from lie_factors.errors import InputError

    from lie_factors.util import atomic

    out_dir = args.output
    if os.path.exists(out_dir) and not os.path.isdir(out_dir):
        raise InputError(f"{out_dir}: exists and is not a directory")
    try:
        os.makedirs(out_dir, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{out_dir}: cannot create directory ({exc.strerror})") from None
    files = os.path.join(out_dir, "trajectory.png"), os.path.join(out_dir, "optimized.g2o")
    atomic.check_writable(files[1])
    return files


def _write_demo(args, files: tuple[str, str], between, values, trajectories: dict, title: str,
                truth=None) -> None:
    """The optimized graph (g2o), the trajectories (png) and, given the ground truth (n, 4, 4)
    with its poses' keys 0 … n−1, ``groundtruth.tum`` beside them, each written atomically."""
    import numpy as np

    import lie_factors as lf
    from lie_factors.util import atomic
    from lie_factors import g2o
    from lie_factors.app.plotting import plot_trajectories
    from lie_factors.evaluation.trajectory import planar_poses

    png, g2o_path = files
    g2o.write_g2o(g2o_path, between, values)
    atomic.replace_atomically(png, lambda tmp: plot_trajectories(tmp, trajectories, title), suffix=".png")
    written = [png, g2o_path]
    if truth is not None:
        path = os.path.join(os.path.dirname(g2o_path), "groundtruth.tum")
        lf.write_trajectory(lf.Trajectory(np.arange(len(truth)), planar_poses(truth)), path)
        written.append(path)
    _say(args, f"wrote {', '.join(written[:-1])} and {written[-1]}")


def _demo_record(args, dataset: str, graph, result, ate0: float, ate1: float, scenario: str | None = None) -> dict:
    """The ``--json`` record of a demo: its graph, ``result``'s figures and the ATE before and after."""
    return {"backend": args.backend, **({"scenario": scenario} if scenario else {}), "dataset": dataset,
            "dimension": 3, "poses": args.poses, "factors": int(graph.size()), "iterations": result.iterations,
            "initial_error": result.initial_error, "final_error": result.error,
            "seconds": result.seconds, "converged": result.converged, "ate_rmse_initial": ate0, "ate_rmse": ate1}


def _run_demo(args) -> int:
    import numpy as np

    from lie_factors.app.compile_note import report_compile

    import lie_factors as lf
    from lie_factors.app import demo
    from lie_factors.backends import factor_namespace

    if args.poses is None:
        args.poses = DEMO_SCENARIOS[args.scenario][0]
    factors = factor_namespace(args.backend)  # a clear error now for an unknown backend
    if args.scenario == "sim3":
        return _run_demo_sim3(args)
    files = _demo_files(args)

    problem = demo.simulate(args.poses, args.seed)
    graph = demo.build_graph(problem, factors)
    _say(args, f"demo: {args.poses} poses, {len(problem.odometry)} odometry edges, "
               f"{len(problem.closures)} loop closures, seed {args.seed}, backend {args.backend}")
    result = lf.optimize(graph, problem.initial, backend=args.backend, max_iterations=args.max_iterations,
                         events=_iterations(args))
    report_compile(args)
    ate0 = demo.ate_rmse(problem.initial, problem.truth)
    ate1 = demo.ate_rmse(result.values, problem.truth)
    status = "converged" if result.converged else "stopped (not converged)"
    _say(args, f"error       {result.initial_error:12.6g} -> {result.error:.6g} "
               f"({result.iterations} iterations, {result.seconds:.3f} s, {status})")
    _say(args, f"ATE (RMSE)  {ate0:12.4f} m -> {ate1:.4f} m")

    from lie_factors.app.plotting import positions

    _write_demo(args, files, demo.between_graph(problem), result.values,
                {"ground truth": [T.translation() for T in problem.truth],
                 "initial": positions(problem.initial, True), "optimized": positions(result.values, True)},
                f"SE(3) pose graph: {args.poses} poses, ATE {ate0:.3f} m -> {ate1:.3f} m",
                truth=np.array([T.matrix() for T in problem.truth]))
    if args.json:
        _emit_json(_demo_record(args, f"demo(poses={args.poses}, seed={args.seed})", graph, result, ate0, ate1))
    return 0


def _run_demo_sim3(args) -> int:
    """The scale-drift scenario (:mod:`lie_factors.app.demo_sim3`): ours and GTSAM's native
    factors on the same Sim(3) graph, ATE and true gradient norm of each result."""
    from lie_factors.app import demo_sim3
    from lie_factors.app.compile_note import report_compile
    from lie_factors.errors import InputError

    if args.backend == "native":
        raise InputError("--scenario sim3 always runs GTSAM's native factors beside ours; "
                       "choose --backend dropin or batch for ours")
    files = _demo_files(args)

    problem = demo_sim3.simulate(args.poses, args.seed)
    _say(args, f"demo sim3: {args.poses} poses, {len(problem.odometry)} odometry edges, "
               f"{len(problem.closures)} loop closures, scale drift e^{demo_sim3.DRIFT[6]:g} per step, "
               f"seed {args.seed}, backend {args.backend} beside native")
    c = demo_sim3.compare(problem, args.backend, args.max_iterations, _iterations(args))
    report_compile(args)
    ours, native, graph = c.ours, c.native, c.graph
    ate0, ate_ours, ate_native = c.ate_initial, c.ate_ours, c.ate_native
    g0, g_ours, g_native = c.gradient_initial, c.gradient_ours, c.gradient_native

    def status(r):
        return "converged" if r.converged else "not converged"

    col = f"ours ({args.backend})"
    _say(args, f"{'':18s}{'initial':>14s}{col:>16s}{'GTSAM native':>16s}")
    _say(args, f"{'error':18s}{ours.initial_error:14.6g}{ours.error:16.10g}{native.error:16.10g}")
    _say(args, f"{'ATE (RMSE) [m]':18s}{ate0:14.4f}{ate_ours:16.4f}{ate_native:16.4f}")
    _say(args, f"{'|true gradient|':18s}{g0:14.3g}{g_ours:16.3g}{g_native:16.3g}")
    _say(args, f"{'  relative':18s}{1.0:14.3g}{g_ours / g0:16.3g}{g_native / g0:16.3g}")
    _say(args, f"{'iterations':18s}{'':14s}{ours.iterations:16d}{native.iterations:16d}")
    _say(args, f"{'seconds':18s}{'':14s}{ours.seconds:16.3f}{native.seconds:16.3f}")
    _say(args, f"{'':18s}{'':14s}{status(ours):>16s}{status(native):>16s}")
    verdict = "a stationary point" if c.stationary else "NOT a stationary point"
    _say(args, f"ours reached {verdict} (|g|/|g0| = {g_ours / g0:.2e}, target <= 1e-06); "
               f"native stopped at |g|/|g0| = {g_native / g0:.2e}")

    n = args.poses
    _write_demo(args, files, demo_sim3.between_graph(problem), ours.values,
                {"ground truth": demo_sim3.true_centres(problem.truth),
                 "initial": demo_sim3.camera_centres(problem.initial, n),
                 "ours": demo_sim3.camera_centres(ours.values, n),
                 "native": demo_sim3.camera_centres(native.values, n)},
                f"Sim(3) scale drift: {n} poses, ATE {ate0:.2f} m -> ours {ate_ours:.3f} m, "
                f"native {ate_native:.3f} m")
    if args.json:
        _emit_json({**_demo_record(args, f"demo-sim3(poses={n}, seed={args.seed})", graph, ours, ate0, ate_ours,
                                   "sim3"),
                    "native_ate_rmse": ate_native, "native_final_error": native.error,
                    "native_iterations": native.iterations, "native_converged": native.converged,
                    "gradient_norm_initial": g0, "gradient_norm": g_ours, "native_gradient_norm": g_native})
    return 0


# --------------------------------------------------------------------------- #
# registry
# --------------------------------------------------------------------------- #

def _add_evaluate(p: argparse.ArgumentParser) -> None:
    p.add_argument("estimate", metavar="ESTIMATE", help="a trajectory (TUM .tum or KITTI .kitti) or a g2o file "
                                                        "(its vertices)")
    p.add_argument("reference", metavar="REFERENCE", help="the ground truth, in the same formats")
    p.add_argument("--align", default="se3", choices=("se3", "sim3", "none"),
                   help="align the estimate to the reference first: se3 (rigid, Umeyama; default), sim3 (with "
                        "scale), none")
    p.add_argument("--delta", type=_bounded_int("--delta", 1, MAX_ITERATIONS), default=1, metavar="N",
                   help="the relative pose error's step, in poses (default: 1)")
    p.add_argument("--plot", metavar="FILE.png", help="the estimate over the reference, coloured by its error")
    p.add_argument("--json", action="store_true", help="print a JSON summary as the last line of stdout")
    p.add_argument("--quiet", action="store_true", help="no human-readable report")


def _run_evaluate(args) -> int:
    """``lie-factors evaluate``: :mod:`lie_factors.app.evaluate`."""
    from lie_factors.app import evaluate

    return evaluate.run(args)


def _add_corrupt(p: argparse.ArgumentParser) -> None:
    from lie_factors.app import corrupt

    corrupt.add_arguments(p, _bounded_int("--seed", 0, MAX_SEED))


def _run_corrupt(args) -> int:
    """``lie-factors corrupt``: :mod:`lie_factors.app.corrupt`."""
    from lie_factors.app import corrupt

    return corrupt.run(args)


def _add_sweep(p: argparse.ArgumentParser) -> None:
    from lie_factors.app import sweep

    sweep.add_arguments(p, _positive_float, _bounded_int)


def _run_sweep(args) -> int:
    """``lie-factors sweep``: :mod:`lie_factors.app.sweep`."""
    from lie_factors.app import sweep

    return sweep.run(args)


#: name → (help, add_arguments(parser), run(args) -> exit status)
SUBCOMMANDS: dict[str, tuple[str, Callable, Callable]] = {
    "demo": ("simulate and optimize a pose graph: SE(3) odometry with loop closures, or "
             "(--scenario sim3) Sim(3) monocular scale drift", _add_demo, _run_demo),
    "posegraph": ("optimize a g2o pose graph with Levenberg-Marquardt", _add_posegraph, _run_posegraph),
    "evaluate": ("the absolute and relative trajectory errors of an estimate against a reference, as evo "
                 "computes them", _add_evaluate, _run_evaluate),
    "corrupt": ("plant false loop closures in a g2o pose graph (uniform, local, group or near), and list "
                "them", _add_corrupt, _run_corrupt),
    "sweep": ("run many cases (graphs, false closures, seeds, methods) on Dask, a row per case in a results "
              "file that a rerun resumes; or summarize and plot one", _add_sweep, _run_sweep),
}

#: Subcommands living in their own module, offered only if the module imports.
OPTIONAL_SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "crosscheck": ("lie_factors.app.crosscheck", "compare lie_factors against GTSAM and mpmath"),
}


def _unavailable(name: str, exc: Exception) -> tuple[str, Callable, Callable]:
    """A stand-in for an optional subcommand whose module exists but fails to import."""
    from lie_factors.errors import InputError

    reason = f"{type(exc).__name__}: {exc}"

    def add(parser):
        parser.add_argument("rest", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)

    def run(args):
        raise InputError(f"{name} is unavailable ({reason})")

    return (f"(unavailable: {reason})", add, run)


def _load_one(name: str) -> tuple[str, Callable, Callable] | None:
    """Import optional subcommand ``name``: its entry, a stand-in if broken, None if absent."""
    module_name, help_text = OPTIONAL_SUBCOMMANDS[name]
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name == module_name:  # not installed/written: simply not offered
            return None
        return _unavailable(name, exc)
    except Exception as exc:  # a broken optional module must not take the whole CLI down
        return _unavailable(name, exc)
    doc = (module.__doc__ or help_text).strip().splitlines()[0]
    if hasattr(module, "add_arguments"):
        return (doc, module.add_arguments, module.main)
    return (doc, _PASSTHROUGH, module.main)


def _exists(module_name: str) -> bool:
    try:
        return importlib.util.find_spec(module_name) is not None
    except (ImportError, ValueError):
        return False


def _deferred(name: str, help_text: str) -> tuple[str, Callable, Callable]:
    """Entry of an optional subcommand that was not imported: listed in --help by its table
    text, imported only when run (``lie-factors --help`` must not load GTSAM or numba)."""

    def run(args):
        return main([name, *args.argv])

    return (help_text, _PASSTHROUGH_DEFERRED, run)


def _load_optional(load=None) -> dict[str, tuple[str, Callable, Callable]]:
    """Optional subcommands: those named in ``load`` (default: all) imported, the rest deferred."""
    found = {}
    for name, (module_name, help_text) in OPTIONAL_SUBCOMMANDS.items():
        if load is None or name in load:
            entry = _load_one(name)
        elif _exists(module_name):
            entry = _deferred(name, help_text)
        else:
            entry = None
        if entry is not None:
            found[name] = entry
    return found


def _PASSTHROUGH(parser):  # marker: main(argv) parses its own arguments
    parser.add_argument("argv", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)


def _PASSTHROUGH_DEFERRED(parser):
    parser.add_argument("argv", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)


def _missing(exc: ImportError) -> str:
    """One line naming the package an ImportError lacks, and how to install it."""
    text = (str(exc).strip().splitlines() or ["an import failed"])[0]
    name = (exc.name or "").split(".")[0]
    return f"{text} (install it: python -m pip install {name})" if name else text


def build_parser(load=None) -> tuple[argparse.ArgumentParser, dict]:
    """The parser and the subcommand table; optional subcommands not in ``load`` are
    deferred (listed, imported when run); ``load=None`` imports them all."""
    commands = {**SUBCOMMANDS, **_load_optional(load)}
    parser = _Parser(
        prog=PROG,
        description="Closed-form Lie-group kernels and GTSAM factors: demos and pose-graph tools.",
    )
    from lie_factors import __version__

    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, (help_text, add, _) in commands.items():
        add(sub.add_parser(name, help=help_text, description=help_text))
    return parser, commands


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the exit status (the console script runs it through :func:`entry`).

    Every :class:`lie_factors.errors.LieFactorsError` is one line on stderr and exit status 2."""
    argv = sys.argv[1:] if argv is None else list(argv)
    # Import only the optional subcommand being run (none for --help).
    parser, commands = build_parser(load=argv[:1])
    try:
        if argv and argv[0] in commands and commands[argv[0]][1] is _PASSTHROUGH:
            # Hand everything after the name over untouched (incl. --help).
            status = commands[argv[0]][2](argv[1:])
        else:
            args = parser.parse_args(argv)  # argparse itself exits 2 on usage errors
            status = commands[args.command][2](args)
    except KeyboardInterrupt:
        print(f"{PROG}: error: interrupted", file=sys.stderr)
        return 130
    except ImportError as exc:  # a package the run needs is missing: say which, in one line
        print(f"{PROG}: error: {_missing(exc)}", file=sys.stderr)
        return EXIT_USAGE
    except Exception as exc:
        from lie_factors.errors import LieFactorsError  # here, not above: --help stays free of numpy

        if not isinstance(exc, LieFactorsError):
            raise
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    return 0 if status is None else int(status)


def entry() -> int:
    """The ``lie-factors`` console script (and ``python -m lie_factors.app.cli``): :func:`main`
    with :mod:`faulthandler` on, then ``gc.freeze()`` before the interpreter exits.

    With faulthandler on, a fatal signal inside compiled code (a segmentation fault)
    prints the Python stack of every thread to stderr, so the crash says where it happened.

    Why: at exit Python sweeps every object it tracks for reference cycles; after a run has
    loaded numba and GTSAM that sweep is a visible part of a small graph's whole command
    (docs/benchmarks.md, "Start-up"). Frozen objects are left out of it. Nothing a run leaves depends on the
    sweep: its output files are written and closed before :func:`main` returns, and the
    standard streams and ``atexit`` handlers are flushed and run at exit as usual. Only
    the console script does this: :func:`main`, called from Python, leaves the caller's
    garbage collector alone.
    """
    faulthandler.enable()
    status = main()
    gc.freeze()
    return status


if __name__ == "__main__":
    sys.exit(entry())
