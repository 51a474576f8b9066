"""VLADriveBench labeler plugin: label each CoT with several LLMs and take the majority vote per label.

The entry module :mod:`vdb_labeler_ensemble.plugin` only registers a factory; the HTTP client, the SQLite
cache and the labeler itself are imported when a labeler is first built.
"""

__version__ = "0.1.0"

LABELER_NAME = "ensemble"
