"""Independent numpy re-check geometry (no coal, no Pinocchio): closed-form distances and
the UR5e collision capsules with their own forward kinematics (world frame, metres)."""
