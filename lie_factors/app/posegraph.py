"""``lie-factors posegraph FILE``: the front door's jobs on a file, with progress lines, files and a record.

1. the options, checked before any work (:func:`lie_factors.solve.options`; the output paths);
2. :func:`lie_factors.read_g2o`;
3. :func:`lie_factors.optimize` (or, with ``--incremental``, :func:`lie_factors.replay`),
   heard through :class:`lie_factors.Events` to print its progress;
4. :func:`lie_factors.write_g2o` or :func:`lie_factors.write_trajectory` (``--output``, by its
   extension) and the plot (``--plot``), each atomically; with ``--groundtruth``, the ATE of the
   start and of the estimate (:func:`lie_factors.evaluate`);
5. with ``--json``, the record as the last line of stdout.
"""

from __future__ import annotations

import json
import sys
import time

import lie_factors as lf
from lie_factors.errors import InputError
from lie_factors.evaluation.trajectory import FORMATS, planar_poses
from lie_factors.events import Events
from lie_factors.files import trajectory_of
from lie_factors.solve import check_graph, options
from lie_factors.util import memory
from lie_factors.util.atomic import check_writable, replace_atomically

from .compile_note import report_compile

#: Keys of the record's ``timings``: the command's steps, in order.
TIMING_KEYS = ("imports", "read", "init", "setup", "iterations", "write")

INIT_DESCRIPTIONS = {
    "chordal": "chordal relaxation (GTSAM's InitializePose3)",
    "lago": "LAGO (GTSAM's lago)",
    "spanning-tree": "measurements composed along a spanning tree",
    "odometry": "the odometry composed from the prior (dead reckoning)",
    "file": "vertices in the file",
}

#: Whose chordal/LAGO initializer ran (lie_factors.initialization.ENGINES), after its description.
ENGINE_NOTES = {"lie_factors": ", ours on arrays", "gtsam": ", GTSAM's own"}

#: GNC's rejecting stages, in the order the pipeline runs them.
STAGES = ("gate", "clique", "gnc", "final")


def flag(keyword: str) -> str:
    """The command-line spelling of an option: ``max_iterations`` → ``--max-iterations``."""
    if keyword == "consistency":
        return "--no-consistency"
    return "--" + keyword.replace("_", "-")


class Printer(Events):
    """The command's progress lines (stderr) and report (stdout), quiet with ``--quiet``."""

    def __init__(self, args, started: float):
        self.args, self.t = args, started

    def say(self, text: str) -> None:
        if not self.args.quiet:
            print(text, flush=True)

    def progress(self, text: str) -> None:
        """A progress line on stderr: elapsed seconds, memory, what is done."""
        if not self.args.quiet:
            print(f"[{time.perf_counter() - self.t:8.2f} s, {memory.describe()}] {text}", file=sys.stderr, flush=True)

    def started(self, start):
        self.progress(f"initialized: {start.method} ({start.seconds:.2f} s)")
        for method, reason in start.skipped:
            self.say(f"init {method} not applicable: {reason}")
        only = (" of the odometry edges and the prior only (loop closures left out under "
                f"{'--gnc' if self.args.gnc else '--robust'})" if start.inliers_only else "")
        self.say(f"initial guess: {INIT_DESCRIPTIONS[start.method]}{ENGINE_NOTES.get(start.engine, '')}"
                 f"{only} ({start.seconds:.3f} s)")

    def set_up(self, seconds):
        self.progress(f"set up ({seconds:.2f} s)")

    def iteration(self, info):
        if not self.args.quiet:
            from lie_factors.lm import format_iteration

            print(f"{format_iteration(info)}  [{time.perf_counter() - self.t:8.2f} s, {memory.describe()}]",
                  file=sys.stderr, flush=True)

    def gnc_iteration(self, iteration, mu, cost, lm_iterations):
        if not self.args.quiet:
            print(f"gnc iter {iteration + 1:3d}  lambda {mu:.3e}  weighted cost {cost:.6e}  "
                  f"({lm_iterations} LM iterations)", file=sys.stderr, flush=True)

    def replayed(self, done, total, seconds):
        if not self.args.quiet:
            print(f"update {done}/{total}: {seconds:.3f} s", file=sys.stderr, flush=True)


def check(args):
    """Everything that can be wrong with the invocation, before the (possibly long) work: the
    options (one-line errors naming the flags) and the output paths."""
    if args.incremental:
        for option, value, default in (("--robust", args.robust, None), ("--robust-all", args.robust_all, False),
                                       ("--init", args.init, "auto"),
                                       ("--max-iterations", args.max_iterations, 100)):
            if value != default:
                raise InputError(f"{option} does not apply to --incremental (ISAM2 replays the file "
                                 "online from its own estimates)")
        opts = None
        if args.backend not in lf.solve.BACKENDS:
            options(backend=args.backend, spell=flag)
        if args.gnc is not None:
            lf.solve.replay_options(backend=args.backend, gnc=args.gnc)
    else:
        if args.relinearize_threshold != lf.solve.RELINEARIZE_THRESHOLD \
                or args.relinearize_skip != lf.solve.RELINEARIZE_SKIP:
            raise InputError("--relinearize-threshold and --relinearize-skip apply to --incremental only")
        opts = options(backend=args.backend, init=args.init, max_iterations=args.max_iterations,
                       robust=args.robust, robust_all=args.robust_all, gnc=args.gnc,
                       consistency=not args.no_consistency, spell=flag)
    for path in (args.output, args.plot, args.covariances):
        if path:
            check_writable(path)
    return opts


def _groundtruth(args):
    """The ground truth of ``--groundtruth``, read (and so checked) before any work, or None."""
    return trajectory_of(args.groundtruth, "the ground truth") if args.groundtruth else None


def _is_trajectory(path: str) -> bool:
    return path.lower().endswith(tuple(FORMATS))


def _ate(out: "Printer", result, truth) -> dict:
    """ATE (SE(3)-aligned) of the start and of the estimate against ``truth``, printed; their JSON."""
    start = lf.Trajectory(result.keys, planar_poses(result.start_poses), True, "start")
    before, after = lf.evaluate(start, truth), lf.evaluate(result, truth)
    out.say(f"ATE (RMSE) against {truth.name or 'the ground truth'}: {before.ate.rmse:.6g} m -> "
            f"{after.ate.rmse:.6g} m (se3-aligned, {after.ate.count} poses)")
    return {"ate_initial": before.ate.to_dict(), "ate": after.ate.to_dict()}


def run(args, imports: float, started: float) -> int:
    """``lie-factors posegraph`` on parsed ``args``; ``imports``: the seconds its imports took."""
    opts = check(args)
    truth = _groundtruth(args)
    out = Printer(args, started)
    t = time.perf_counter()
    pg = lf.read_g2o(args.dataset)
    if opts is not None:
        check_graph(pg, opts, spell=flag)
    timings = {"imports": imports, "read": time.perf_counter() - t}
    out.progress(f"read and checked ({timings['read']:.2f} s)")
    if args.incremental:
        out.say(f"{pg.describe()}; incremental (ISAM2, relinearize threshold {args.relinearize_threshold:g}, "
                f"skip {args.relinearize_skip}), backend {args.backend}")
        result = lf.replay(pg, backend=args.backend, relinearize_threshold=args.relinearize_threshold,
                           relinearize_skip=args.relinearize_skip, gnc=args.gnc, events=out)
        out.say(f"{result.updates} updates in {result.update_seconds:.3f} s (per update: median "
                f"{result.update_p50 * 1e3:.3f} ms, p99 {result.update_p99 * 1e3:.3f} ms); "
                f"final error {result.error:.6g}")
        if result.gnc is not None:
            out.say(f"online {result.gnc.upper()}: rejected {len(result.outliers)} of {len(pg.loop_closures())} "
                    f"loop closures; {result.seconds:.3f} s in all (the updates, then every decision tested "
                    "again at the end)")
            if result.robust_status["status"] != "ok":
                out.say("uncertain: " + "; ".join(result.robust_status["reasons"]))
        report_compile(args)
    else:
        out.say(f"{pg.describe()}{' (no vertices in the file)' if pg.vertices is None else ''}; "
                f"backend {opts.backend}")
        if opts.robust is not None:
            out.say(f"robust loss {opts.robust} on {'every edge' if opts.robust_all else 'the loop closures'}")
        result = lf.optimize(pg, backend=opts.backend, init=opts.init, max_iterations=opts.max_iterations,
                             robust=opts.robust, robust_all=opts.robust_all, gnc=opts.gnc,
                             consistency=opts.consistency, events=out)
        out.progress(f"optimized ({result.timings.get('iterations', 0.0):.2f} s)")
        report_compile(args)
        _report(out, args, pg, result)
    timings.update({k: result.timings.get(k, 0.0) for k in ("init", "setup", "iterations")})
    accuracy = _ate(out, result, truth) if truth is not None else {}
    t = time.perf_counter()
    write(out, args, pg, result)
    timings["write"] = time.perf_counter() - t
    if args.json:
        print(json.dumps({**record(pg, result, timings, args), **accuracy}), flush=True)
    return 0


def _report(out: Printer, args, pg, result) -> None:
    status = "converged" if result.converged else "stopped (not converged)"
    if result.gnc is not None:
        stages = ""
        if result.rejected_by is not None:
            counts = {s: list(result.rejected_by.values()).count(s) for s in STAGES}
            stages = " (" + ", ".join(f"{counts[s]} by {s}" for s in STAGES) + ")"
        out.say(f"GNC-{result.gnc.upper()}: rejected {len(result.outliers)} of {len(pg.loop_closures())} loop "
                f"closures{stages}; error {result.initial_error:.6g} -> weighted {result.error:.6g} after "
                f"{result.iterations} GNC iterations, {result.seconds:.3f} s (+ {result.init_seconds:.3f} s "
                f"initialization), {status}")
        if result.robust_status is not None and result.robust_status["status"] != "ok":
            out.say("uncertain: " + "; ".join(result.robust_status["reasons"]))
    else:
        out.say(f"error {result.initial_error:.6g} -> {result.error:.6g} after {result.iterations} iterations, "
                f"{result.seconds:.3f} s (+ {result.init_seconds:.3f} s initialization), {status}")


def write(out: Printer, args, pg, result) -> None:
    """``--output`` (g2o, TUM or KITTI), ``--covariances`` (npz) and ``--plot`` (png), each atomically."""
    if args.output:
        if _is_trajectory(args.output):
            lf.write_trajectory(result, args.output)
        else:
            lf.write_g2o(result, args.output)
        out.progress(f"wrote {args.output}")
        out.say(f"wrote {args.output}")
    if args.covariances:
        lf.write_covariances(result, args.covariances)
        out.progress(f"wrote {args.covariances}")
        out.say(f"wrote {args.covariances}")
    if args.plot:
        from .plotting import plot_result

        incremental = args.incremental
        title = f"{pg.name} ({result.backend}{', incremental' if incremental else ''})"
        ellipses = args.covariances is not None and not pg.is3d
        replace_atomically(args.plot, lambda tmp: plot_result(tmp, pg, result, title, incremental, ellipses),
                           suffix=".png")
        out.progress(f"wrote {args.plot}")
        out.say(f"wrote {args.plot}")


def record(pg, result, timings: dict, args) -> dict:
    """The ``--json`` record: the graph's facts, then the result's figures (:meth:`lie_factors.Result.to_dict`)."""
    head = {"backend": result.backend, "dataset": pg.name, "dimension": 3 if pg.is3d else 2,
            "poses": pg.pose_count, "landmarks": pg.landmark_count, "factors": int(result.factors)}
    if args.incremental:
        return {**head, **result.to_dict(), "relinearize_threshold": float(args.relinearize_threshold),
                "relinearize_skip": int(args.relinearize_skip)}
    return {**head, **result.to_dict(), "timings": {k: timings.get(k, 0.0) for k in TIMING_KEYS}}
