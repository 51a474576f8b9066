"""Internal to the core: plugins never import this package (see vladrivebench.__all__)."""
