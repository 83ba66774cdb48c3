"""``aslip check grasp-axes``: the grasp plane's orientation in the finger rigid body,
measured against the TCP by a short sweep of the arm, written into the cell file.

Why: robot-induced labels are read in the TCP's grasp plane (``grasp_plane_in_tcp``),
externally induced ones in the finger body's (``grasp_plane_in_finger``). Both default to
identity, which is right only in the scene, where the finger body is the TCP; on a cell
whose finger rigid body is rotated on the gripper the two data sets disagree by that
rotation (90 deg about the pad normal swaps vx and vz), the model learns both, and
slip-track moves the wrong way.

How: the TCP's grasp plane is the reference (``grasp_plane_in_tcp``: the gripper's
geometry as the arm's TCP is configured; the arm moves along its axes). The arm moves the
gripper (holding the clamped probe lightly, or nothing) ``distance`` along the grasp
plane's +x, back, then along +z and back, with velocity commands inside the arm's limits
(:class:`aslip_ros.bringup.arm_check.ArmCheck`). Before and after each outward leg the
TCP (from the arm) and the finger body (from motion capture, averaged while still) are
read; the TCP's displacement in its grasp plane ``a`` and the finger body's in its own
frame ``b`` satisfy ``b = R a`` with ``R`` the grasp plane's orientation in the finger
body, found from the two legs by :meth:`scipy.spatial.transform.Rotation.align_vectors`
(Wahba's problem). Each leg must be as long in motion capture as at the arm, and ``R``
must explain both legs, else the finger body is not on this gripper (or the units, or the
clocks are off) and nothing is written.

The grasp plane's origin in the finger body (``aslip check grasp-plane``) is kept; the
orientation replaces the cell's. ROS-free: the arm and the finger poses come in through
:class:`FingerPoses` and the :class:`~aslip_ros.arm.Arm` protocol (the xArm
adapter and ROS on a cell, :class:`SceneCell` in the simulated scene). On a cell the finger
body's poses come from its PoseStamped topic or, with mocap4r2, from its body of the
RigidBodies, as the cell's ``mocap_bridge`` section or the options say
(:mod:`aslip_ros.bringup.mocap_source`).
"""

from __future__ import annotations

import collections
import time
from dataclasses import dataclass, replace
from types import SimpleNamespace
from typing import Callable, Optional, Protocol, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from aslip_ros.arm import ArmError
from aslip_ros.bringup.arm_check import ArmCheck
from aslip_ros.bringup.mocap_source import MocapSource, resolve
from aslip_ros.bringup.mocap_source import add_arguments as add_source_arguments
from aslip_ros.bringup.verdict import Verdict
from aslip_ros.poses import IDENTITY_POSE, as_pose

#: The grasp-plane axes swept, in order: two axes of the pad plane (a clamped probe slides
#: along the pads, never pushed into one).
AXES = {'+x': (1.0, 0.0, 0.0), '+z': (0.0, 0.0, 1.0)}
DEFAULT_DISTANCE_M = 0.02
DEFAULT_SPEED_M_S = 0.01
#: Finger poses are averaged over this long once the arm has stopped [s].
AVERAGE_S = 0.3
#: A leg measured by motion capture may differ in length from the arm's by this much [m].
TOLERANCE_M = 0.003
#: The rotation must bring every TCP leg onto the finger's within this angle [deg].
MAX_RESIDUAL_DEG = 5.0


class FingerPoses(Protocol):
    """The finger rigid body's poses from motion capture."""

    def mean_pose(self, seconds: float) -> np.ndarray:
        """The finger pose ``(x, y, z, qx, qy, qz, qw)`` in the mocap world, averaged over
        the next ``seconds``; raises ValueError when no pose arrives."""


@dataclass(frozen=True)
class Leg:
    """One outward leg: the TCP's displacement in its grasp plane and the finger body's in
    its own frame [m]."""

    axis: str
    tcp_in_grasp_plane: np.ndarray
    finger_in_body: np.ndarray


@dataclass(frozen=True)
class GraspAxes:
    """The grasp plane's orientation in the finger body (quaternion x y z w) and its fit."""

    quat: np.ndarray
    legs: tuple
    residual_deg: float

    def grasp_plane_in_finger(self, origin: Sequence[float]) -> list:
        """The pose7 with the cell's measured origin and this orientation."""
        return [float(x) for x in list(origin)[:3]] + [float(x) for x in self.quat]


def solve(legs: Sequence[Leg]) -> GraspAxes:
    """The rotation taking the TCP's legs (grasp plane) onto the finger's (finger body).

    :raises ValueError: fewer than two legs, or legs that do not span a plane.
    """
    if len(legs) < 2:
        raise ValueError(f'the orientation needs two legs along different axes, got {len(legs)}')
    a = np.array([leg.tcp_in_grasp_plane for leg in legs], dtype=np.float64)
    b = np.array([leg.finger_in_body for leg in legs], dtype=np.float64)
    for name, v in (('arm', a), ('motion capture', b)):
        n = np.linalg.norm(v, axis=1)
        if np.any(n < 1e-4) or np.linalg.norm(np.cross(v[0], v[1])) < 0.5 * n[0] * n[1]:
            raise ValueError(f'the legs seen by the {name} do not span a plane '
                             f'({np.round(v * 1e3, 1).tolist()} mm): did it move?')
    rot, _ = Rotation.align_vectors(b, a)
    fit = rot.apply(a)
    cos = np.sum(fit * b, axis=1) / (np.linalg.norm(fit, axis=1) * np.linalg.norm(b, axis=1))
    residual = float(np.degrees(np.max(np.arccos(np.clip(cos, -1.0, 1.0)))))
    quat = rot.as_quat()
    return GraspAxes(quat * (1.0 if quat[3] >= 0 else -1.0), tuple(legs), residual)


def verdict(result: Optional[GraspAxes], legs: Sequence[Leg], distance: float,
            verdict_: Optional[Verdict] = None) -> Verdict:
    """FAIL when a leg is too short, the two sensors disagree on a leg's length, or the
    rotation does not explain both legs."""
    v = verdict_ or Verdict()
    for leg in legs:
        arm, mocap = (float(np.linalg.norm(x)) for x in (leg.tcp_in_grasp_plane,
                                                         leg.finger_in_body))
        if abs(arm - distance) > TOLERANCE_M:
            v.fail(f'the TCP moved {arm * 1e3:.1f} mm along {leg.axis}, not {distance * 1e3:g} '
                   'mm: the arm did not follow (run aslip check arm)')
        elif abs(arm - mocap) > TOLERANCE_M:
            v.fail(f'along {leg.axis} the finger body moved {mocap * 1e3:.1f} mm, the TCP '
                   f'{arm * 1e3:.1f} mm: is the finger rigid body on this gripper, and '
                   'tracked in metres?')
    if result is not None and result.residual_deg > MAX_RESIDUAL_DEG:
        v.fail(f'no one rotation explains both legs (off by {result.residual_deg:.1f} deg, '
               f'at most {MAX_RESIDUAL_DEG:g}): the finger body turned or slipped on the '
               'gripper; fix it and run again')
    return v


def sweep(arm, finger: FingerPoses, grasp_plane_in_tcp: Sequence[float], speed: float,
          distance: float, out, clock: Callable[[], float] = time.monotonic,
          sleep: Callable[[float], None] = time.sleep) -> list:
    """Move out and back along each of :data:`AXES` of the TCP's grasp plane; the legs.
    The arm is stopped after each leg (and by the caller's ``finally``)."""
    mover = ArmCheck(arm, out, clock=clock, sleep=sleep)
    plane = Rotation.from_quat(as_pose(grasp_plane_in_tcp, 'grasp_plane_in_tcp')[3:])
    legs = []
    for name, axis in AXES.items():
        tcp0 = np.asarray(arm.tcp_pose(), dtype=np.float64)
        f0 = finger.mean_pose(AVERAGE_S)
        to_base = Rotation.from_quat(tcp0[3:]) * plane       # grasp plane -> link_base
        direction = to_base.apply(axis)
        mover.leg(direction, speed, distance)
        tcp1 = np.asarray(arm.tcp_pose(), dtype=np.float64)
        f1 = finger.mean_pose(AVERAGE_S)
        leg = Leg(name, to_base.inv().apply(tcp1[:3] - tcp0[:3]),
                  Rotation.from_quat(f0[3:]).inv().apply(f1[:3] - f0[:3]))
        legs.append(leg)
        print(f'{name}: TCP {np.round(leg.tcp_in_grasp_plane * 1e3, 1).tolist()} mm '
              f'(grasp plane), finger body {np.round(leg.finger_in_body * 1e3, 1).tolist()} '
              'mm (its own frame)', file=out, flush=True)
        mover.leg(-direction, speed, distance)
    return legs


def measure(arm, finger: FingerPoses, cell_values: dict, speed: float = DEFAULT_SPEED_M_S,
            distance: float = DEFAULT_DISTANCE_M, out=None, clock=time.monotonic,
            sleep=time.sleep) -> tuple:
    """Run the sweep; ``(verdict, {section: {key: pose7}} to write, or None)``.

    ``cell_values``: the cell's ``grasp_plane_in_finger`` and ``grasp_plane_in_tcp`` (absent:
    identity). The arm is stopped at the end, on any error and on Ctrl-C.
    """
    v = Verdict()
    tcp_plane = list(cell_values.get('grasp_plane_in_tcp') or IDENTITY_POSE)
    finger_plane = list(cell_values.get('grasp_plane_in_finger') or IDENTITY_POSE)
    if not (0.0 < speed and 0.0 < distance):
        raise ValueError(f'--speed and --distance must be > 0, got {speed:g}, {distance:g}')
    legs = []
    try:
        arm.enable_velocity_mode()
        legs = sweep(arm, finger, tcp_plane, speed, distance, out, clock, sleep)
    except ArmError as exc:
        v.fail(f'the arm refused: {exc}')
    except ValueError as exc:
        v.fail(str(exc))
    finally:
        try:
            arm.stop()
        except ArmError as exc:
            v.fail(f'stopping the arm failed: {exc}: use the emergency stop')
    if not v.ok:
        return v, None
    try:
        result = solve(legs)
    except ValueError as exc:
        return v.fail(str(exc)), None
    verdict(result, legs, distance, v)
    turned = float(np.degrees(Rotation.from_quat(result.quat).magnitude()))
    print(f'grasp plane in the finger body: quaternion {np.round(result.quat, 5).tolist()} '
          f'({turned:.1f} deg from identity; fit within {result.residual_deg:.2f} deg)',
          file=out)
    if not v.ok:
        return v, None
    return v, {'mocap_bridge': {'grasp_plane_in_finger':
                                result.grasp_plane_in_finger(finger_plane[:3])},
               'arm': {'grasp_plane_in_tcp': [float(x) for x in tcp_plane]}}


class SceneCell:
    """The simulated scene as a cell for this check: its arm (commanded, a probe in the
    grasp), its clock, and its finger poses with the rigid body mounted ``finger_mount``
    (quaternion x y z w: the body's orientation in the grasp plane; identity = the scene's
    own, where the finger body is the TCP)."""

    def __init__(self, seed: int = 0, finger_mount: Sequence[float] = (0.0, 0.0, 0.0, 1.0),
                 block_s: float = 0.01, **scenario) -> None:
        from aslip_ros.scene import World
        from aslip_ros.scene.scenarios import robot_induced
        scn = robot_induced(seed, **dict(dict(layout='2mic_corners', sample_rate=8000.0,
                                              duration_s=None), **scenario))
        self.world = World(replace(scn, commanded_arm=True))
        self.arm = self.world.arm
        self.arm.connect()
        self._mount = Rotation.from_quat(as_pose([0, 0, 0, *finger_mount], 'mount')[3:])
        self._block = max(1, int(round(block_s * self.world.fs)))
        self._recent: collections.deque = collections.deque(maxlen=10000)

    def clock(self) -> float:
        """Scene time [s]."""
        return self.world.t

    def sleep(self, seconds: float) -> None:
        """Let ``seconds`` of scene time pass, keeping the finger poses that arrive."""
        end = self.world.t + max(0.0, float(seconds))
        while self.world.t < end - 0.5 / self.world.fs:
            n = max(1, min(self._block, int(round((end - self.world.t) * self.world.fs))))
            for s in self.world.step(n).mocap:
                pose = np.asarray(s.finger_pose, dtype=np.float64)
                q = (Rotation.from_quat(pose[3:]) * self._mount).as_quat()
                self._recent.append((s.t, np.concatenate([pose[:3], q])))

    def mean_pose(self, seconds: float) -> np.ndarray:
        """The finger pose averaged over the next ``seconds`` of scene time."""
        t0 = self.world.t
        self.sleep(seconds)
        got = np.array([p for t, p in self._recent if t >= t0 - 1e-9])
        if not len(got):
            raise ValueError(f'no finger pose in {seconds:g} s of motion capture')
        return np.concatenate([got[:, :3].mean(axis=0),
                               Rotation.from_quat(got[:, 3:]).mean().as_quat()])


def check_grasp_axes(cell_path: str, out, confirm: Callable[[str], bool],
                     speed: float = DEFAULT_SPEED_M_S, distance: float = DEFAULT_DISTANCE_M,
                     finger_topic: Optional[str] = None, ip: Optional[str] = None,
                     scene_turn_deg: Optional[float] = None, write: bool = True,
                     finger_body: Optional[str] = None,
                     rigid_bodies_topic: Optional[str] = None) -> int:
    """The bring-up step: sweep, measure, write into the cell file; the exit code.

    The finger's poses: ``finger_topic`` (PoseStamped), or ``finger_body`` of the RigidBodies
    on ``rigid_bodies_topic``; else as the cell's ``mocap_bridge`` section says
    (:func:`aslip_ros.bringup.mocap_source.resolve`). ``scene_turn_deg`` not None: the
    simulated scene instead of the cell's arm and motion capture, its finger body turned
    that much about the pad normal.
    """
    from aslip_ros.bringup.cell_edit import set_cell_values
    from aslip_ros.cell import load_cell
    cell = load_cell(cell_path)
    current = {'grasp_plane_in_finger': cell.get('mocap_bridge', 'grasp_plane_in_finger'),
               'grasp_plane_in_tcp': cell.section('arm').get('grasp_plane_in_tcp')}
    question = (f'move the gripper {distance * 100:g} cm along the grasp plane\'s +x and back, '
                f'then +z and back, at {speed * 100:g} cm/s?')
    if scene_turn_deg is not None:
        mount = Rotation.from_rotvec([0.0, np.radians(scene_turn_deg), 0.0]).as_quat()
        scene = SceneCell(finger_mount=mount)
        print(f'the simulated scene, its finger body turned {scene_turn_deg:g} deg about the '
              'pad normal', file=out)
        v, values = measure(scene.arm, scene, current, speed, distance, out, scene.clock,
                            scene.sleep)
    else:
        source = resolve(SimpleNamespace(finger_topic=finger_topic, finger_body=finger_body,
                                         rigid_bodies_topic=rigid_bodies_topic), cell,
                         ('finger',))
        if not confirm(question):
            return Verdict().fail('not confirmed; nothing moved').report(out)
        v, values = _on_the_cell(cell, current, speed, distance, out, source, ip)
    if values is not None and current['grasp_plane_in_tcp'] is not None:
        del values['arm']               # the reference, as the cell has it: left untouched
    if values is not None and write:
        set_cell_values(cell_path, values)
        for section, keys in values.items():
            for key, value in keys.items():
                print(f'written into {cell_path}: {section}.{key} '
                      f'{[round(x, 6) for x in value]}', file=out)
    elif values is not None:
        print('not written (--dry-run)', file=out)
    return v.report(out)


def _on_the_cell(cell, current: dict, speed: float, distance: float, out,
                 source: MocapSource, ip: Optional[str]) -> tuple:
    """The cell's xArm (its ``arm`` section) and its finger poses over ROS."""
    from aslip_ros.bringup.arm_check import arm_config
    from aslip_ros.hw.xarm import XArmAdapter
    from aslip_ros.nodes.finger_watch import FingerWatch
    arm_section = cell.section('arm')
    ip = ip or arm_section.get('xarm_ip')
    if not ip:
        raise ValueError('the cell\'s arm section has no xarm_ip (or pass --ip)')
    config = arm_config(str(ip), arm_section.get('arm_max_speed_m_s'),
                        arm_section.get('arm_workspace_min_m') or None,
                        arm_section.get('arm_workspace_max_m') or None)
    arm = XArmAdapter(config)
    watch = FingerWatch(source.rigid_bodies_topic, source.bodies['finger']) if source.rigid \
        else FingerWatch(source.topics['finger'])
    print(f'the finger\'s poses: {source.text()}', file=out, flush=True)
    try:
        try:
            arm.connect()
        except ArmError as exc:
            return Verdict().fail(f'cannot connect: {exc}; nothing moved'), None
        return measure(arm, watch, current, speed, distance, out)
    finally:
        arm.close()
        watch.close()


def add_arguments(p) -> None:
    """``aslip check grasp-axes``'s options."""
    p.add_argument('--setup', metavar='FILE', required=True,
                   help='the cell file: its arm and motion capture; the result is written '
                   'into it (mocap_bridge.grasp_plane_in_finger, arm.grasp_plane_in_tcp)')
    p.add_argument('--speed', type=float, default=DEFAULT_SPEED_M_S, help='sweep speed [m/s]')
    p.add_argument('--distance', type=float, default=DEFAULT_DISTANCE_M,
                   help='length of each leg [m]')
    add_source_arguments(p, ('finger',))
    p.add_argument('--ip', help='xArm controller IP (default: the cell\'s xarm_ip)')
    p.add_argument('--dry-run', action='store_true', help='measure, do not write the cell')
    p.add_argument('--scene', action='store_true',
                   help='the simulated scene instead of the cell\'s arm and motion capture')
    p.add_argument('--scene-finger-turn-deg', type=float, default=0.0, metavar='DEG',
                   help='--scene: the finger rigid body turned this much about the pad normal')
    p.add_argument('--yes', action='store_true', help='move without asking')


def run(args, out, confirm: Callable[[str], bool]) -> int:
    """``aslip check grasp-axes`` with parsed ``args``."""
    return check_grasp_axes(args.setup, out, confirm, args.speed, args.distance,
                            args.finger_topic, args.ip,
                            args.scene_finger_turn_deg if args.scene else None,
                            write=not args.dry_run, finger_body=args.finger_body,
                            rigid_bodies_topic=args.rigid_bodies_topic)
