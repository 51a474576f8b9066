"""An example third-party VLA adapter (see README.md)."""
