"""What crosses the network: key space, payloads, Zenoh configuration, access control, traffic.

- :mod:`wire.keys`: key builders and :func:`wire.keys.key_class`.
- :mod:`wire.payloads`: versioned payload types, ``encode`` and defensive ``decode_*``.
- :mod:`wire.zconf`: ``zenoh.Config`` from typed settings or command-line flags.
- :mod:`wire.acl`: the fleet's users, credentials and access control list.
- :mod:`wire.traffic`: traffic counters, a counting publisher, the asyncio mailbox.
"""
