"""The transformers adapter toolkit for VLADriveBench (see :mod:`vdb_adapter_transformers.toolkit`).

Importing this package is light; ``vdb_adapter_transformers.toolkit`` imports torch and transformers.
"""

__version__ = "0.1.0"
