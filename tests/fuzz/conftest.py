"""The fuzz suite's own modules (``harness``, ``cases``) are imported by name: put this folder on ``sys.path``
once (pytest runs with ``--import-mode=importlib``, which does not)."""

import sys
from pathlib import Path

FUZZ = str(Path(__file__).resolve().parent)
if FUZZ not in sys.path:
    sys.path.insert(0, FUZZ)
