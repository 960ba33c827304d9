"""Build/dev-time benchmarks: work-precision, stress (stability) suite, equation timings.

Nothing here is imported by the FMU run time. matplotlib, tqdm, scipy, exudyn, pinocchio and fmpy are
imported lazily inside the functions that need them.
"""

__all__ = ["work_precision", "stress", "equations", "bench_main", "stress_main", "benchmark_equations"]


def bench_main(argv=None):
    """`mbsfmu bench SCENE --out DIR [--quick] [--methods ...]`."""
    from .work_precision import bench_main as _main
    return _main(argv)


def stress_main(argv=None):
    """`mbsfmu stress --out DIR [--quick]`."""
    from .stress import stress_main as _main
    return _main(argv)


def benchmark_equations(scene_path, out_dir=None, **kw):
    """Evaluator.equations vs Pinocchio crba + nonLinearEffects (and an fmpy run of the FMU if possible)."""
    from .equations import benchmark_equations as _b
    return _b(scene_path, out_dir, **kw)
