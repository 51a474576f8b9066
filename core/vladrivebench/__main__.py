"""``python -m vladrivebench ARGS`` is ``vdb ARGS``."""

import sys

from vladrivebench._cli.main import main

sys.exit(main())
