"""What crosses the network: key space, payloads, Zenoh configuration, router, traffic.

- :mod:`wire.keys`: key builders and :func:`wire.keys.key_class`.
- :mod:`wire.payloads`: versioned payload types, ``encode`` and defensive ``decode_*``.
- :mod:`wire.zconf`: ``zenoh.Config`` from typed settings or command-line flags.
- :mod:`wire.router`: a Python router session (``python -m wire.router``).
- :mod:`wire.traffic`: traffic counters, a counting publisher, the asyncio mailbox.
- :mod:`wire.ports`: loopback ports: a free one, its endpoint, waiting for a listener.
- :mod:`wire.testing`: loopback helpers for tests and benchmarks (a router process, matching).
"""
