"""One run's configuration (``formation run``), frozen and checked once where it is built.

The command builds a :class:`RunConfig` from its options (so do the experiments and tests that
start runs from Python) and hands it to :func:`simulator.launch.launch`, which only orchestrates
the run. Every check of the options' combinations lives in :meth:`RunConfig.__post_init__`: a bad
one is a ``ValueError`` with one line naming the option, which the command reports as invalid
input (exit 2) before anything starts.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from agent.qp import make_solver
from scenario import Scenario
from wire.rmw_zenoh import RmwSettings

from .faults import FaultPlan
from .fleet import RemoteAgents
from .lifelong import fleet_base
from .physics import ENGINES
from .physics import available as physics_available

CAMERAS = ("truth", "synthetic", "process")
RESTART_POLICIES = ("on-failure", "no")


@dataclass(frozen=True)
class RunConfig:
    """Everything a multi-process run is started with (see :mod:`simulator.launch`).

    Over 20 fields on purpose: one frozen record of every option of ``formation run``, checked
    once where it is built, so that no later part reads an option unchecked.

    ``faults`` injects the faults of :class:`simulator.faults.FaultPlan`; ``secure`` runs the
    router with user/password authentication and the access control list of :mod:`wire.acl`,
    every process logging in as itself. ``pose_slots`` and ``clock_offset`` [s] are the world's
    (:class:`simulator.world.WorldOptions`: real time only). ``solver`` is the agents' QP solver
    (:func:`agent.qp.make_solver`). ``camera="process"`` also starts the real camera process
    (``python -m camera_service``) on the frames the world renders; it reads the static obstacles
    from ``scenario_path``. ``agents_per_process`` K > 1 runs the agents K to an agent host
    (:mod:`agent.host`; ``shared_session``: one Zenoh session per host). ``hold`` keeps the fleet
    up after every goal is reached, until the scenario's duration or SIGINT/SIGTERM. ``engine``
    "mujoco" has MuJoCo move the world's robots (:mod:`simulator.physics`), as ``formation sim
    --engine mujoco`` does: a lock-step run writes the same robots.csv.
    ``pose_zones`` Z > 0 carries the poses and commands through Z zone routers of the world's
    process (:mod:`simulator.zones`). ``remote`` places the agents of ``remote.robots`` on other
    hosts (``--hosts``, :mod:`deploy.remote`); the router then listens on ``remote.endpoint``.
    ``rmw_base`` (``--base rmw_zenoh``): every agent drives its robot's base over rmw_zenoh
    (namespace = robot id), which the world plays (:mod:`simulator.bases`).
    A scenario with a fleet (lifelong operation) is kept as its robots, each a formation of one
    (:func:`simulator.lifelong.fleet_base`), its ``lifelong`` part beside them: the launcher
    starts the fleet manager and the world keeps the loads (:mod:`simulator.world_loads`).
    """

    scenario: Scenario
    out: Path
    realtime: bool = False
    camera: str = "truth"
    topology: str = "reduced"
    safety: bool = True
    port: int = 0  # the router's loopback port; 0: a free one
    faults: FaultPlan = field(default_factory=FaultPlan)
    secure: bool = True
    pose_slots: int = 1
    scenario_path: Path | None = None
    clock_offset: float = 0.0  # [s]
    agents_per_process: int = 1
    shared_session: bool = False
    solver: str = "exact"
    hold: bool = False
    remote: RemoteAgents | None = None
    pose_zones: int = 0
    rmw_base: RmwSettings | None = None
    restart: str = "on-failure"  # a crashed local agent is restarted (as systemd on a robot)
    restart_limit: int = 3  # ... at most this many times per robot; then the run aborts
    engine: str = "kinematic"  # what moves the robots in the world: or "mujoco" (simulator.physics)

    def __post_init__(self) -> None:
        object.__setattr__(self, "out", Path(self.out))
        if self.scenario.lifelong is not None and not self.scenario.formations:
            object.__setattr__(self, "scenario", fleet_base(self.scenario))
        if self.scenario_path is not None:
            object.__setattr__(self, "scenario_path", Path(self.scenario_path))
        self._check_camera()
        self._check_clock()
        self._check_hosting()
        make_solver(self.solver)  # an unknown or missing backend: before any process starts
        self.faults.check_robots(self.scenario.robot_ids)
        self._check_remote()
        self._check_rmw_base()
        self._check_engine()
        self._check_fleet()
        self._check_localisation()

    def _check_fleet(self) -> None:
        """Lifelong operation: the world hears the teams' statuses on the session its commands
        come on, and frames are whole (its loads go out before them)."""
        if self.scenario.lifelong is None:
            return
        for bad, why in ((self.pose_slots > 1, "--pose-slots"), (self.pose_zones, "--pose-zones"),
                         (self.rmw_base is not None, "--base rmw_zenoh"),
                         (self.camera != "truth", f"--camera {self.camera}")):
            if bad:
                raise ValueError(f"fleet: {why} is not supported with lifelong operation (the "
                                 "world takes the teams' statuses with the commands of whole "
                                 "frames, on true poses)")

    def _check_localisation(self) -> None:
        """``fused``: the world publishes whole frames and every robot's odometry."""
        if self.scenario.controller.localisation != "fused":
            return
        if self.pose_slots > 1:
            raise ValueError("--pose-slots: not with controller.localisation fused (the world "
                             "publishes each robot's odometry with its frame)")

    def _check_engine(self) -> None:
        if self.engine not in ENGINES:
            raise ValueError(f"--engine: {self.engine!r} is not one of {', '.join(ENGINES)}")
        if self.engine == "mujoco" and not physics_available():
            raise ValueError("--engine mujoco: MuJoCo is not installed "
                             "(pip install 'formation-cbf[physics]')")

    def _check_rmw_base(self) -> None:
        if self.rmw_base is None:
            return
        if not self.scenario.robot.is_unicycle:
            raise ValueError("--base rmw_zenoh: a ROS base takes (v, omega): needs a unicycle "
                             "scenario")
        if self.rmw_base.cmd_type == "Twist" and not self.realtime:
            raise ValueError("--cmd-type Twist: carries no stamp to match lock-step ticks; "
                             "needs --realtime")

    @property
    def fault_run(self) -> bool:
        return self.faults.active

    def _check_camera(self) -> None:
        if self.camera not in CAMERAS:
            raise ValueError(f"--camera: {self.camera!r} is not one of {', '.join(CAMERAS)}")
        if self.camera in ("synthetic", "process"):
            try:  # lazily: keeps OpenCV off the runs that do not render frames
                import camera_service.service  # noqa: F401
            except ImportError:
                raise ValueError("--camera synthetic: camera_service.service is not available "
                                 "yet") from None
        if self.camera == "process" and self.faults.camera_dropouts:
            raise ValueError("--camera-dropout: not with --camera process (the camera process "
                             "publishes the poses)")
        if self.camera == "process" and self.scenario_path is None:
            raise ValueError("scenario_path: --camera process needs the scenario file")

    def _check_clock(self) -> None:
        if not 0 <= self.port < 65536:
            raise ValueError(f"--port: {self.port} is not a TCP port")
        if self.pose_slots < 1:
            raise ValueError(f"--pose-slots: need an integer >= 1, got {self.pose_slots}")
        if self.pose_slots > 1 and not self.scenario.world.ideal:
            raise ValueError(f"--pose-slots: not in the {self.scenario.world.profile} world (its "
                             "camera publishes whole frames)")
        if self.pose_slots > 1 and not (self.realtime and self.camera == "truth"):
            raise ValueError("--pose-slots: more than one slot needs --realtime and --camera truth")
        if self.clock_offset and not self.realtime:
            raise ValueError("--clock-offset-ms: needs --realtime (lock-step runs on simulated "
                             "time)")

    def _check_hosting(self) -> None:
        if self.pose_zones < 0:
            raise ValueError(f"--pose-zones: need an integer >= 0, got {self.pose_zones}")
        if self.pose_zones and self.remote is not None:
            raise ValueError("--pose-zones: the zone routers listen on loopback only; not with "
                             "--hosts")
        if self.restart not in RESTART_POLICIES:
            raise ValueError(f"--restart: {self.restart!r} is not one of "
                             f"{', '.join(RESTART_POLICIES)}")
        if self.restart_limit < 0:
            raise ValueError(f"--restart-limit: need an integer >= 0, got {self.restart_limit}")
        if self.agents_per_process < 1:
            raise ValueError(f"--agents-per-process: need an integer >= 1, got "
                             f"{self.agents_per_process}")
        if self.agents_per_process > 1 and self.faults.kills:
            raise ValueError("--kill: needs one agent per process (--agents-per-process 1)")
        if self.shared_session and self.secure:
            raise ValueError("shared session: each robot logs in as itself with secure; not both")

    def _check_remote(self) -> None:
        if self.remote is None:
            return
        if self.port:
            raise ValueError("--port: not with --hosts (the router listens on the inventory's "
                             "zenoh.router)")
        for k in self.faults.kills:
            if k.robot in self.remote.robots:
                raise ValueError(f"--kill: {k.robot} runs on another host (--hosts); kills "
                                 f"need an agent on this machine")
