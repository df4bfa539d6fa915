"""The bus: the only Zenoh plumbing, shared by the planner's processes and the drivers.

- :mod:`planner.bus.session`: key expressions (:class:`~planner.bus.session.Keys`), sessions
  and their endpoints and configuration files, publisher priorities, message encoding and
  decoding with located errors, liveliness;
- :mod:`planner.bus.bodies`: JSON bodies read within limits and written in bounded pieces;
- :mod:`planner.bus.priority`: real-time priority for the threads safety waits on;
- :mod:`planner.bus.ids`: trajectory (chunk) ids and the request they belong to;
- :mod:`planner.bus.events`: the processes' event log (one ``key=value`` line an event).

It imports nothing of the planner but :mod:`planner.errors` and :mod:`schemas`, so a driver
can use it without the planner's maths.
"""
