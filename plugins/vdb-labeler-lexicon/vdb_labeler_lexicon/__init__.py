"""Deterministic, offline CoT labeler for VLADriveBench (labeler name ``lexicon``)."""

__version__ = "0.1.0"
