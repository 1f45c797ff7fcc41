"""Where an update of the incremental smoother's replay spends its time: compiled kernels, GTSAM, Python.

    python benchmarks/incremental_profile.py [--datasets intel kitti_00 parking-garage sphere2500 FILE.g2o ...]
        [--repeat 2] [--top 12]

For each graph: the replay of :func:`lie_factors.incremental.replay.replay` (the default
command's), best of ``--repeat`` update seconds without a profiler; then one replay under
cProfile, whose time inside each compiled kernel and each GTSAM call is read as it is (a call
into compiled code costs the profiler one entry and one exit, whatever it does inside).  The
Python share is the update seconds less those two: what the interpreter runs per update.
Prints the shares and the ``--top`` functions by own time, and the dense elimination work of
the replay (Σ D·N² over fronts, the block factor's count) and the largest front.
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from lie_factors.g2o import read_pose_graph  # noqa: E402
from lie_factors.incremental.replay import new_isam, replay_arrays, warm_up_smoother  # noqa: E402


def load(name: str):
    for candidate in (ROOT / "data" / f"{name}.g2o", Path(name)):
        if candidate.is_file():
            return read_pose_graph(str(candidate))
    raise SystemExit(f"no graph {name}")


def shares(stats: pstats.Stats) -> tuple[float, float, dict]:
    """(compiled seconds, GTSAM seconds, own seconds by function) of a profiled replay."""
    compiled = gtsam_s = 0.0
    own = {}
    for (path, line, name), (cc, nc, tt, ct, callers) in stats.stats.items():
        label = f"{Path(path).name}:{line}({name})" if path != "~" else name
        own[label] = (tt, nc)
        if path != "~":
            continue
        if "gtsam" in name:
            gtsam_s += tt
        elif "lie_factors" in name or "call" == name:
            compiled += tt
    return compiled, gtsam_s, own


def profile(name: str, repeat: int, top: int) -> None:
    pg = load(name)
    warm_up_smoother(pg.group)
    best = None
    for _ in range(repeat):
        r = replay_arrays(pg, new_isam("batch"))
        best = r if best is None or r.update_seconds < best.update_seconds else best
    smoother = new_isam("batch")
    prof = cProfile.Profile()
    prof.enable()
    replay_arrays(pg, smoother)
    prof.disable()
    compiled, gtsam_s, own = shares(pstats.Stats(prof))
    n = best.updates
    python = best.update_seconds - compiled - gtsam_s
    bf = smoother.bf
    print(f"## {pg.name}: {n} updates, update seconds {best.update_seconds:.3f} (p99 {best.update_p99 * 1e3:.2f} ms), "
          f"final error {best.error:.10g}")
    print(f"compiled {compiled:.3f} s ({compiled / n * 1e6:.0f} µs/update), GTSAM {gtsam_s:.3f} s "
          f"({gtsam_s / n * 1e6:.0f} µs/update), Python {python:.3f} s ({python / n * 1e6:.0f} µs/update)")
    print(f"dense work Σ D·N² {int(bf.work.stats[6]):.3g}, columns re-eliminated {bf.totals.columns}, "
          f"relinearized {smoother.relinearizations}, reorderings {smoother.reorderings}")
    for label, (tt, nc) in sorted(own.items(), key=lambda kv: -kv[1][0])[:top]:
        print(f"  {tt:8.3f} s  {nc:8d}  {label}")
    sys.stdout.flush()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--datasets", nargs="+", default=["intel", "kitti_00", "parking-garage", "sphere2500"])
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--top", type=int, default=12)
    args = ap.parse_args(argv)
    print(f"# load: {subprocess.run(['uptime'], capture_output=True, text=True).stdout.strip()}")
    print(f"# OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}")
    for name in args.datasets:
        profile(name, args.repeat, args.top)
    return 0


if __name__ == "__main__":
    sys.exit(main())
