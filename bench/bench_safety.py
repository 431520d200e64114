"""Issue 14's long safety runs (too long for ``make test``): 7 robots from 100 random starts,
exact and with camera noise and latency, and the Robotarium task's separation.

Prints, per sensing model, the least centre separation over all 100 trials (bodies touch at
0.150 m), how many robots reached their goals within 5 cm in 25 s, and the 5 smallest per-trial
separations; then the anchor task (``anchor-triangle``): minimum separation and the RMS
formation error after settling; and paper-exp2's leader (the role swap must be kept).

``--estimator`` runs everything with the firmware's estimator on (its pose at now, its
uncertainty handed to the filter beyond ``noise_budget_m``): the default to come.

Run: ``.venv/bin/python bench/bench_safety.py [--trials N] [--estimator]``. A measurement: it
fails only if two bodies touch (the tests' assertion, reused).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))  # the closed-loop harness: tests/support/safety_runs.py


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=100, help="random starts (default 100)")
    ap.add_argument("--skip-random", action="store_true", help="only the scenario figures")
    ap.add_argument("--estimator", action="store_true", help="the firmware's estimator on")
    args = ap.parse_args(argv)

    import dataclasses

    import numpy as np

    from formation.outputs import metrics
    from formation.sim import simulate
    from robot_agent.core import AgentConfig, EstimatorParams
    from scenario import load

    def est_on(agent: AgentConfig) -> AgentConfig:
        if not args.estimator:
            return agent
        return dataclasses.replace(
            agent, estimator=dataclasses.replace(agent.estimator, enabled=True)
        )

    if not args.skip_random:
        from support.safety_runs import EXACT, NOISY, random_starts_run

        cfg = AgentConfig(estimator=EstimatorParams(enabled=args.estimator))
        for name, sensing in (("exact", EXACT), ("noisy", NOISY)):
            t0 = time.perf_counter()
            worst, reached, total, seps = random_starts_run(args.trials, sensing, cfg=cfg)
            print(
                f"7 robots x {args.trials} random starts ({name}): min separation {worst:.4f} m, "
                f"reached {reached}/{total} ({100 * reached / total:.1f} %), "
                f"smallest {', '.join(f'{s:.3f}' for s in sorted(seps)[:5])} "
                f"({time.perf_counter() - t0:.0f} s)",
                flush=True,
            )
    for name in ("anchor-triangle", "paper-exp2", "corridor"):
        scn = load(name)
        scn = scn.with_overrides(agent=est_on(scn.agent))
        res = simulate.run(scn)
        m = metrics.compute(res.log, metrics.settle_for(scn.settle_s, scn.duration_s),
                            scn.settle_tol_m)  # fmt: skip
        rms = [r["formation_error_rms_m"] for r in m["robots"].values()]
        saf = m["safety"]
        print(
            f"{name}: min separation {m['run']['min_separation_m']:.4f} m, RMS formation error "
            f"(mean of robots) {1e3 * float(np.mean(rms)):.3f} mm, final leader "
            f"{m['run']['final_leader']}, role changes {m['run']['role_change_count']}, "
            f"tie-breaks {saf['tiebreaks']}, filter active "
            f"{100 * saf['filter_active_fraction']:.1f} %, time below Ds "
            f"{saf['time_below_ds_s']:.2f} s, boundary violations {saf['boundary_violations']}",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
