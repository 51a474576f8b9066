"""Registration only: cheap to import. The model module is imported when the model is first built."""

import vladrivebench


def make_pixel_vla(cruise_speed: float = 6.0, red_threshold: float = 0.002, obstacle_threshold: float = 0.004,
                   coupling: float = 1.0):
    """Options become ``--model-opt key=value`` on the command line."""
    from .model import PixelVLA

    return PixelVLA(cruise_speed=cruise_speed, red_threshold=red_threshold,
                    obstacle_threshold=obstacle_threshold, coupling=coupling)


@vladrivebench.hookimpl
def register_models(register):
    register("pixel-vla", make_pixel_vla, description="example camera-only VLA (examples/vla-adapter)")
