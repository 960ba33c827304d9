"""The reports users run on their own scenes: `mbsfmu bench` (work_precision.py: error against run time, scipy
and Exudyn beside the engine) and `mbsfmu stress` (stress.py: the stability suite on stiff and extreme cases).

Nothing here is imported by the FMU run time. matplotlib, tqdm, scipy and exudyn are imported lazily inside the
functions that need them. The developer benchmarks are the repository's benchmarks/ folder, not shipped.
"""

__all__ = ["work_precision", "stress", "bench_main", "stress_main"]


def bench_main(argv=None):
    """`mbsfmu bench SCENE --out DIR [--quick] [--methods ...]`."""
    from .work_precision import bench_main as _main
    return _main(argv)


def stress_main(argv=None):
    """`mbsfmu stress --out DIR [--quick]`."""
    from .stress import stress_main as _main
    return _main(argv)
