"""The simulated cell in one process: the drivers' simulators (camera, tracker, servo lag) on a
hidden truth, driven by the planner's own code, for the studies and benchmarks that measure
the product on it without a bus. The one layer below the entry points that imports drivers."""
