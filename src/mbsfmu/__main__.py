"""`python -m mbsfmu ...`: the `mbsfmu` command (cli.py)."""

import sys

from .cli import main

sys.exit(main())
