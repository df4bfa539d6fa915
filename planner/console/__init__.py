"""The operator console: a browser page (viser) on the running system.

It is a Zenoh client of the planner's public interface (docs/conventions.md section 6): it shows the live
point cloud, robots, beam, spot and node health; the operator clicks targets on the cloud,
previews the plan, executes it and stops it. ``beamrelay console SCENARIO`` or
``beamrelay up SCENARIO --console``.
"""

from planner.console.cloud import Cloud, cloud_from_sample, decimate
from planner.console.picking import Pick, PlaneFit, fit_plane, pick_point, surface_normal
from planner.console.targets import Mode, Target, TargetList, build_request

__all__ = [
    "Cloud",
    "Mode",
    "Pick",
    "PlaneFit",
    "Target",
    "TargetList",
    "build_request",
    "cloud_from_sample",
    "decimate",
    "fit_plane",
    "pick_point",
    "surface_normal",
]
