"""CoT truncation as a VLADriveBench intervention paradigm (an example of a third-party paradigm)."""
