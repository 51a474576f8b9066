"""Property tests of the plugin's rule-based computations: the scanline rasteriser of user networks' ground.

(The road users' scripts are the core's, tested in ``tests/test_world_motion.py``.)"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from matplotlib.path import Path as PolygonPath
from vdb_sim_sumo.usernet import _Raster


@st.composite
def convex_polygons(draw):
    cx, cy = draw(st.floats(5.0, 15.0)), draw(st.floats(5.0, 15.0))
    angles = sorted(draw(st.lists(st.floats(0.0, 2 * math.pi, exclude_max=True), min_size=3, max_size=8,
                                  unique=True)))
    radius = draw(st.floats(0.5, 4.0))
    return [(cx + radius * math.cos(a), cy + radius * math.sin(a)) for a in angles]


@settings(max_examples=80, deadline=None)
@given(convex_polygons())
def test_the_rasteriser_fills_exactly_the_cells_whose_centres_are_inside(polygon):
    grid = np.zeros((100, 100), dtype=np.uint8)
    _Raster(grid, (0.0, 0.0), 0.2).fill(polygon, 7)
    centres = (np.stack(np.meshgrid(np.arange(100), np.arange(100)), -1).reshape(-1, 2) + 0.5) * 0.2
    inside = PolygonPath(polygon).contains_points(centres).reshape(100, 100)
    filled = grid == 7
    # cells whose centre lies within 1e-9 of an edge may go either way
    assert np.count_nonzero(filled != inside) <= 2
    assert np.count_nonzero(filled) >= np.count_nonzero(inside) - 2
