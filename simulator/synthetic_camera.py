"""The synthetic camera of ``formation run --camera synthetic``: an overhead frame of the true
poses rendered and the markers detected back by the camera service (:mod:`camera_service`)."""

from __future__ import annotations

from collections.abc import Sequence

from scenario import Scenario
from scenario.world import blind_at

SYNTH_IMAGE = (1920, 1440)  # [px] the synthetic camera's frame
SYNTH_TILT = 0.1  # perspective tilt of the synthetic camera (far edge 10 % shorter)
SYNTH_MARKER_PX = 26.0  # [px] smallest marker side the synthetic camera must resolve


class SyntheticCamera:
    """Render an overhead frame of the true poses and detect the markers back (camera_service).

    The camera sees the scenario's floor (every start, goal and static obstacle, plus 1 m) in a
    SYNTH_IMAGE frame with a mild perspective tilt; each robot carries ArUco marker k (its index
    in the scenario), sized to at least SYNTH_MARKER_PX pixels so the camera can resolve it.
    A marker the detector misses publishes nothing that tick (the agent sees a stale pose); a
    robot on blind floor (``world.camera_blind``) is not in the frame at all."""

    def __init__(self, scenario: Scenario) -> None:
        from camera_service import CameraConfig, CameraService, synthetic_camera

        xs = [r.start[0] for r in scenario.robots] + [r.goal[0] for r in scenario.robots]
        ys = [r.start[1] for r in scenario.robots] + [r.goal[1] for r in scenario.robots]
        for o in scenario.obstacles:
            if o.velocity == (0.0, 0.0):
                xs += [o.center[0] - o.safe_distance, o.center[0] + o.safe_distance]
                ys += [o.center[1] - o.safe_distance, o.center[1] + o.safe_distance]
        arena = (min(xs) - 1.0, min(ys) - 1.0, max(xs) + 1.0, max(ys) + 1.0)
        self.calibration = synthetic_camera(image_size=SYNTH_IMAGE, arena=arena, tilt=SYNTH_TILT)
        scale = min((SYNTH_IMAGE[0] - 32) / (arena[2] - arena[0]),
                    (SYNTH_IMAGE[1] - 32) / (arena[3] - arena[1]))  # [px/m] near edge
        self.marker_side = max(0.08, SYNTH_MARKER_PX / (scale * (1.0 - SYNTH_TILT)))  # [m]
        self.marker_ids = {rid: k for k, rid in enumerate(scenario.robot_ids)}
        self.radius = scenario.robot.radius
        self.service = CameraService(CameraConfig(self.calibration, marker_ids=self.marker_ids))
        self.blind = scenario.world.camera_blind

    def poses(self, state: Sequence[Sequence[float]],
              obstacles: Sequence[tuple[float, float, float]],
              stamp: float) -> dict[str, tuple[float, float, float]]:
        """The poses the detector finds in the frame of ``state`` (robot -> x, y, theta);
        ``obstacles``: (x, y, safe distance) drawn into the frame."""
        from camera_service import render_aruco_frame

        truth = {rid: (s[0], s[1], s[2]) for rid, s in zip(self.marker_ids, state, strict=True)
                 if not blind_at(self.blind, s[0], s[1])}
        frame = render_aruco_frame(truth, self.calibration, self.marker_ids, obstacles,
                                   marker_side=self.marker_side, robot_radius=self.radius)
        return {o.robot_id: (o.x, o.y, o.theta) for o in self.service.process(frame, stamp)}
