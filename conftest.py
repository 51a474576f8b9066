"""Settings for every test of the repository (the core's, the plugins' and the examples').

On CI (``CI`` set, as ``.ci/run`` runs) hypothesis is derandomized and keeps no example database, so a run
on a fresh machine tries exactly the examples a developer's ``CI=true make test`` tried.
"""

import os

from hypothesis import settings

settings.register_profile("ci", derandomize=True, database=None, print_blob=True)
if os.environ.get("CI"):
    settings.load_profile("ci")
