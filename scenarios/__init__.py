"""The shipped scenarios (YAML files in this folder), installed with the package so that the
demo, the studies and the benchmarks find them from any install: see
:func:`planner.data.shipped_scenario`."""
