"""The SUMO simulator for VLADriveBench: registers simulator ``sumo`` (SUMO through libsumo)."""

__version__ = "0.1.0"
