"""Building a simulator: roads and routes from a scenario, scripted road users, ground truth, a camera.

The public API for simulator plugins (``vdb-sim-kinematic`` and ``vdb-sim-sumo`` are built on it). A
simulator reads a :class:`~vladrivebench.Scenario`, builds its road with :func:`build_road`, moves the ego
with :func:`apply_control` (the kinematic bicycle model at :data:`DT`), places road users with
:func:`scripted_users`, tracks the ground truth with :class:`TruthTracker` and renders its cameras with
:class:`Camera`: a rig of named cameras (:data:`RIG_PRESETS`, built from options by :func:`rig_from_options`
and :func:`check_history_options`) whose frame and pose history a :class:`RigRecorder` keeps. Scenario files are read with
:func:`load_scenario_file` / :func:`parse_scenario`, the installed suite with :func:`load_suite`.
"""

from vladrivebench._scenarios.spec import load_scenario_file, load_suite, parse_scenario
from vladrivebench.world._bicycle import (
    BRAKE_DECEL,
    DT,
    EGO_LENGTH,
    EGO_WIDTH,
    MAX_WHEEL_ANGLE,
    THROTTLE_ACCEL,
    WHEELBASE,
    advance,
    apply_control,
)
from vladrivebench.world._boxes import Box, colliding, overlap
from vladrivebench.world._camera import Camera, count_pixels_differing
from vladrivebench.world._motion import (
    WORLD_FEATURES,
    ScriptedUser,
    blank_image,
    check_numbers,
    check_supported,
    check_view_options,
    ego_at_start,
    option_error,
    scripted_users,
)
from vladrivebench.world._rig import (
    ALPAMAYO_RIG,
    FRONT_RIG,
    RIG_PRESETS,
    CameraRig,
    RigRecorder,
    check_history_options,
    rig_from_options,
    route_text,
)
from vladrivebench.world._roads import (
    GRASS,
    KERB,
    MARK_WHITE,
    MARK_YELLOW,
    ROAD,
    ROAD_BEHIND,
    ROUTE_STEP,
    SIDEWALK,
    FeaturePose,
    Prop,
    RoadGeometry,
    Route,
    StopLine,
    build_road,
    junction_arms,
)
from vladrivebench.world._truth import TruthTracker, feature_actors

__all__ = [
    "load_scenario_file", "load_suite", "parse_scenario",
    "BRAKE_DECEL", "DT", "EGO_LENGTH", "EGO_WIDTH", "MAX_WHEEL_ANGLE", "THROTTLE_ACCEL", "WHEELBASE", "advance",
    "apply_control",
    "Box", "colliding", "overlap",
    "Camera", "count_pixels_differing",
    "ALPAMAYO_RIG", "FRONT_RIG", "RIG_PRESETS", "CameraRig", "RigRecorder", "check_history_options",
    "rig_from_options", "route_text",
    "WORLD_FEATURES", "ScriptedUser", "blank_image", "check_numbers", "check_supported", "check_view_options",
    "ego_at_start", "option_error", "scripted_users",
    "GRASS", "KERB", "MARK_WHITE", "MARK_YELLOW", "ROAD", "ROAD_BEHIND", "ROUTE_STEP", "SIDEWALK", "FeaturePose", "Prop", "RoadGeometry",
    "Route", "StopLine", "build_road", "junction_arms",
    "TruthTracker", "feature_actors",
]
