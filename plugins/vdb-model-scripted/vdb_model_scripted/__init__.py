"""The scripted reference VLA: ground-truth perception, a templated CoT with exactly known error rates, and
an action head that mixes a CoT-driven and a perception-driven speed policy with weight ``alpha``.

Importing this package is cheap (numpy only); the plugin module registers the model ``scripted``.
"""

__version__ = "0.1.0"
