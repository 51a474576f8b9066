"""Make the example importable from a fresh clone: `make install` installs only `plugins/*`, so that an
example never shows up in a user's `vdb list-plugins` unless they install it themselves."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
