#!/usr/bin/env python3
"""Build an FMU from a scene: `python build_fmu.py SCENE.yaml -o OUTDIR` writes OUTDIR/<name>.fmu."""

import sys

from mbsfmu.cli import main

if __name__ == "__main__":
    sys.exit(main(["build", *sys.argv[1:]]))
