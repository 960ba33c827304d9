"""Developer benchmarks (not shipped): the engine against its peers (Pinocchio, Exudyn, MuJoCo, fmpy hosts), speed
by tree size, model exchange against co-simulation, sweeps, FE reduction. Run from a source checkout, e.g.
`python -m benchmarks.tree_speed --out reports`; `python -m benchmarks.report` regenerates reports/. The reports
users run on their own scenes (`mbsfmu bench`, `mbsfmu stress`) are the package's (mbsfmu.reports).
"""

import sys
from pathlib import Path

# the Pinocchio twin of a scene is the tests' oracle (tests/pinocchio_twin.py); the benchmarks time the same twin
sys.path.append(str(Path(__file__).resolve().parents[1] / "tests"))
