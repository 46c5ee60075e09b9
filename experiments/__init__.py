"""The experiments: measurements that run the simulator and the agents, above both layers.

* :mod:`experiments.bench` - ``formation bench`` (control step, solvers, centralized QP,
  agent fleets, in-process throughput), with :mod:`experiments.central`,
  :mod:`experiments.agents`, :mod:`experiments.fleet_scenario` and :mod:`experiments.machine`.
* :mod:`experiments.commcost` - ``formation commcost``: communication cost of both topologies.
* :mod:`experiments.montecarlo` - ``formation montecarlo``: random warehouse scenarios.

The command-line handlers live in :mod:`formation.commands`; ``benchmarks/`` scripts import from
here.
"""
