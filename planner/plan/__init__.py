"""The planning pipeline, above the solvers: a scenario's targets -> the plan.

- :mod:`~planner.plan.scenario_planner`: :class:`ScenarioPlanner`, the scenario's rules (IK,
  scene, safety, surface tolerance), the one constructor behind every entry point; points
  solved in order, paths swept.
- :mod:`~planner.plan.landing`, :mod:`~planner.plan.occlusion`, :mod:`~planner.plan.gaps`:
  the post-steps of a solve (camera-frame targets landed on their surface, blocked beams
  re-solved or failed, dropped path samples as gaps).
- :mod:`~planner.plan.document`: the checker's re-verification and the plan.json document.
- :mod:`~planner.plan.timed`, :mod:`~planner.plan.safe_timing`: the trajectory, timed under
  the safety rules.
- :mod:`~planner.plan.pipeline`: :class:`Pipeline` and :func:`run_scenario` (``beamrelay
  plan``, the API, the planner node).
"""
