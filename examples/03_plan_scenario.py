"""03: plan a whole scenario (IK of every target, visit order, timed trajectory) and
re-verify the plan with the independent numpy checker.

Run: python examples/03_plan_scenario.py
"""

from pathlib import Path

import planner

SCENARIO = Path(__file__).resolve().parents[1] / "scenarios" / "n2_relay.yaml"

doc = planner.plan(SCENARIO)
m = doc["metrics"]
print(f"{m['n_ok']}/{m['n_targets']} targets solved, max error {1e3 * m['error_max']:.2e} mm")
print(f"trajectory: {m['duration']:.1f} s, {len(doc['trajectory']['t'])} samples")
for result in planner.check_plan(doc):
    verdict = "ok" if not result.findings else f"{len(result.findings)} violations"
    print(f"check {result.name}: {result.checked} checked, {verdict}")
