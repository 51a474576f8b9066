"""The kinematic simulator for VLADriveBench: registers simulator ``kinematic``."""

__version__ = "0.1.0"
