"""The tables and the figure of a salience run, from results with an identifiable and an unidentifiable fit."""

from __future__ import annotations

import math

from vdb_paradigm_salience.paradigm import cells_table, override_plot, threshold_table
from vdb_paradigm_salience.stats import logistic_threshold, wilson


def cell(kind, offset, distance, pixels, overrides, trials, seeds=20):
    low, high = wilson(overrides, trials)
    salience = {"n": seeds, "pixels": float(pixels), "pixel_share": pixels / 12800, "bbox_pixels": float(pixels),
                "angular_width_deg": 1.0, "angular_height_deg": 2.0, "solid_angle_deg2": 2.0,
                "distance": float(distance), "speed": 7.0}
    return {"key": f"{kind}_o{offset:g}_d{distance:g}_x1", "kind": kind, "offset": offset, "distance": distance,
            "size": 1.0, "counts": {"seeds": seeds, "baseline_stopped": trials, "baseline_collisions": 0,
                                    "injected_collisions": overrides, "overrides": overrides, "trials": trials},
            "override_rate": overrides / trials if trials else None, "low": low, "high": high, "salience": salience}


def results():
    cells = [cell("pedestrian", -1.0, 50, 4, 15, 20), cell("pedestrian", -1.0, 25, 9, 9, 20),
             cell("pedestrian", 0.0, 50, 6, 11, 20), cell("pedestrian", 0.0, 25, 14, 3, 20),
             cell("car", 0.0, 50, 6, 0, 20), cell("car", -1.0, 50, 9, 0, 20), cell("car", 0.0, 25, 40, 0, 0)]
    fits = {k: logistic_threshold([(c["salience"]["pixels"], c["counts"]["overrides"], c["counts"]["trials"])
                                   for c in cells if c["kind"] == k]) for k in ("pedestrian", "car")}
    return {"model": {"name": "kv", "options": {}}, "seeds": list(range(20)), "confidence": 0.95,
            "salience": {"base_route": "SAFE.kerb-ped", "obstacle": "ped0", "condition": "accel",
                         "contrast": "contrast is not varied", "cells": cells, "fits": fits}}


def test_every_cell_shows_its_counts_and_its_interval():
    table = cells_table(results())
    rows = {r.labels: r.cells for r in table.rows}
    kerb = rows[("pedestrian", "-1", "50", "×1")]
    assert kerb[6].display == "15/20" and kerb[7].display.startswith("75 % [") and kerb[7].count == 20
    assert kerb[7].low < 0.75 < kerb[7].high
    assert rows[("car", "0", "25", "×1")][7].display == "— (0/0)"


def test_the_threshold_is_fitted_for_pedestrians_and_not_identifiable_for_cars():
    data = results()
    assert data["salience"]["fits"]["pedestrian"]["identifiable"]
    rows = {r.labels[0]: r.cells for r in threshold_table(data).rows}
    assert rows["pedestrian"][4].display == "fitted" and rows["pedestrian"][2].value < 0
    assert rows["car"][3].display == "not identifiable" and "no trial was overridden" in rows["car"][4].display


def test_the_plot_has_every_cell_with_its_trials_and_the_fit_and_renders():
    plot = override_plot(results())
    panels = dict(plot.panels)
    ped = next(series for title, series in panels.items() if title.startswith("pedestrian: 50 % at"))
    cells, fit = ped
    assert cells.counts == (20, 20, 20, 20) and list(cells.x) == sorted(cells.x)
    assert cells.x[0] == math.log10(4) and fit.label == "logistic fit" and fit.y[0] > fit.y[-1]
    assert any(t.startswith("car: threshold not identifiable") for t in panels)
    png = plot.to_png(dpi=40)
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    assert plot.to_json()["panels"][0]["series"][0]["counts"] == [20, 20, 20, 20]
