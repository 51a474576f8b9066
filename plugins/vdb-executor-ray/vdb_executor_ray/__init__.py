"""A Ray executor for VLADriveBench sweeps (``vdb run --executor ray [--address …]``)."""

__version__ = "0.1.0"
