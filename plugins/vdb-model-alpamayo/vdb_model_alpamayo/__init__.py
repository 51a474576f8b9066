"""VLADriveBench model plugin for the Alpamayo 1 / 1.5 architecture (see README.md)."""
