"""The batching tests reuse ``test_alpamayo``'s helpers by name: put this folder on ``sys.path`` (the suite
imports test files with ``--import-mode=importlib``, which does not)."""

import sys
from pathlib import Path

TESTS = str(Path(__file__).resolve().parent)
if TESTS not in sys.path:
    sys.path.insert(0, TESTS)
