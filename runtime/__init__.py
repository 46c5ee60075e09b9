"""Process plumbing shared by the fleet's processes (no control math, no payloads).

- :mod:`runtime.router`: a Python Zenoh router session (``python -m runtime.router``).
- :mod:`runtime.lifeline`: children stop when their launcher dies (pipe and ``PR_SET_PDEATHSIG``).
- :mod:`runtime.shutdown`: one ordered shutdown per process, run once, from any thread.
- :mod:`runtime.heap`: the heap frozen after start-up.
- :mod:`runtime.ports`: loopback ports: a free one, its endpoint, waiting for a listener.
- :mod:`runtime.testing`: loopback helpers for tests and benchmarks (a router process, matching).
"""
