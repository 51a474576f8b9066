"""VLADriveBench paradigm plugin: the visual-salience threshold of a "road is clear, accelerate" override."""
