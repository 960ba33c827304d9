"""Regenerate reports/: work-precision for the shipped models (rigid and elastic), stress suite, equation timings.

    python -m benchmarks.report [--out reports] [--stop 2] [--skip-stress]
"""

import argparse
import os
from pathlib import Path

MODELS = ("pendulum", "double_pendulum", "cart_pole", "robot_arm_6dof", "spinning_top", "driven_crank",
          "spring_damper", "free_body", "crane", "flexible_pendulum", "spinup_beam", "robot_arm_elastic", "fe_link")


def main(argv=None):
    from mbsfmu.reports import stress, work_precision

    from . import equations
    p = argparse.ArgumentParser()
    p.add_argument("--out", default="reports")
    p.add_argument("--stop", type=float, default=2.0)
    p.add_argument("--budget", type=float, default=20.0)
    p.add_argument("--models", nargs="+", default=MODELS)
    p.add_argument("--skip-stress", action="store_true")
    p.add_argument("--skip-wp", action="store_true")
    a = p.parse_args(argv)
    models = Path(stress.scene_dir()).parent
    if not a.skip_wp:
        for m in a.models:
            path = models / f"{m}.yaml"
            if path.exists():
                work_precision.run(str(path), os.path.join(a.out, m), stop=a.stop, budget=a.budget, progress=False)
                print("done", m, flush=True)
    equations.benchmark_equations(str(models / "robot_arm_6dof.yaml"), a.out, stop=a.stop)
    if not a.skip_stress:
        stress.run(a.out, progress=False)


if __name__ == "__main__":
    main()
