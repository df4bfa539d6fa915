"""Per-target beam IK: exact closed-form family, Newton polish, IPOPT NLP (see ``solve``)."""

from planner.ik.solve import EXACT, BeamIK, IKOptions, Solution

__all__ = ["EXACT", "BeamIK", "IKOptions", "Solution"]
