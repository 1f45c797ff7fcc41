"""The scale-drift scenario over several seeds: ours against GTSAM's native Similarity3 factors.

For each seed: ATE before/after and the true gradient norm (exact Jacobians) at
each optimizer's result, relative to the initial one, plus LM iterations and
seconds (best of ``--repeat`` runs, ours and native alternated).  Prints a
Markdown table (docs/benchmarks.md, section "Sim(3) scale drift").

    python benchmarks/sim3_scale_drift.py [--poses 150] [--seeds 5]
"""

from __future__ import annotations

import argparse

from lie_factors.app import demo_sim3


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--poses", type=int, default=150)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--backend", default="dropin")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    demo_sim3.compare(demo_sim3.simulate(20, 0), args.backend)  # compile outside the timings
    print(f"{args.poses} poses, backend {args.backend} vs GTSAM native, LM with demo_sim3.lm_params()")
    print("| seed | closures | ATE initial [m] | ATE ours [m] | ATE native [m] | error ours | error native "
          "| ‖g‖/‖g0‖ ours | ‖g‖/‖g0‖ native | iterations ours / native | seconds ours / native |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for seed in range(args.seeds):
        problem = demo_sim3.simulate(args.poses, seed)
        runs = [demo_sim3.compare(problem, args.backend) for _ in range(args.repeat)]
        c = runs[0]
        t_ours = min(r.ours.seconds for r in runs)
        t_native = min(r.native.seconds for r in runs)
        print(f"| {seed} | {len(problem.closures)} | {c.ate_initial:.2f} | {c.ate_ours:.4f} | {c.ate_native:.4f} "
              f"| {c.ours.final_error:.6f} | {c.native.final_error:.6f} "
              f"| {c.gradient_ours / c.gradient_initial:.1e} | {c.gradient_native / c.gradient_initial:.1e} "
              f"| {c.ours.iterations} / {c.native.iterations} | {t_ours:.3f} / {t_native:.3f} |", flush=True)


if __name__ == "__main__":
    main()
