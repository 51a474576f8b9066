"""Example metric plugin for VLADriveBench: the distance at which a model first mentions the target."""
