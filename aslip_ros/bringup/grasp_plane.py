"""``aslip check grasp-plane``: the grasp-plane origin in the finger rigid body, measured from
a short recording of the object held still in the grasp.

The finger track is interpolated at each object pose's stamp (both from the bag's header
stamps, as the exporter pairs them), the pairs go to
:func:`aslip_ros.data.labels.measure_grasp_plane`, and the object's position in the finger
frame must not wander more than ``max_spread_m`` from its median over the recording:
otherwise the object moved, and its mean position is not where the pads hold it.

The poses are the finger's and the object's PoseStamped topics or, for mocap4r2's drivers,
their bodies of one RigidBodies topic (:mod:`aslip_ros.bringup.mocap_source` chooses, from
the options or the cell file; :func:`aslip_ros.rigid_bodies.select_bodies` decodes).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from aslip_ros.bringup.mocap_source import MocapSource
from aslip_ros.bringup.verdict import Verdict
from aslip_ros.data.bags import POSE_TYPE, BagError, BagReader
from aslip_ros.data.labels import PoseTrack, measure_grasp_plane
from aslip_ros.poses import IDENTITY_POSE, compose, invert
from aslip_ros.rigid_bodies import RIGID_BODIES_TYPE, ROLES, BodyTally, select_bodies

#: Mocap noise is well below a millimetre; more spread than this is motion.
DEFAULT_MAX_SPREAD_M = 0.003
#: Fewer pose pairs than this is not a measurement.
MIN_PAIRS = 10
#: The cell file's section whose ``grasp_plane_in_finger`` this is (mocap_bridge's
#: parameter: the cell file's sections are named after the nodes, aslip_ros/cell.py).
SETUP_SECTION = 'mocap_bridge'


@dataclass(frozen=True)
class GraspPlaneResult:
    """The measured ``grasp_plane_in_finger`` (pose7), the pairs it came from, the spread."""

    pose: np.ndarray
    pairs: int
    duration_s: float
    spread_m: float
    frame_ids: tuple

    def setup_lines(self) -> str:
        """The lines to paste into the cell setup file."""
        values = ', '.join(f'{v:.5f}' for v in self.pose)
        return f'{SETUP_SECTION}:\n  grasp_plane_in_finger: [{values}]'


def read_pose_tracks(bag: str | os.PathLike, source: MocapSource):
    """(finger PoseTrack, object PoseTrack, frame ids) of a bag, by header stamp: from the
    PoseStamped topics of ``source``, or its bodies of the RigidBodies topic (a body missing
    from some messages is a gap of its track; from all of them, a BagError naming the
    bodies there are)."""
    data = {r: ([], []) for r in ROLES}
    frames = set()
    wanted = [source.rigid_bodies_topic] if source.rigid else \
        [source.topics[r] for r in ROLES]
    tally = BodyTally(source.bodies)
    with BagReader(bag) as reader:
        reader.require(wanted, _why(reader, source))
        expected = RIGID_BODIES_TYPE if source.rigid else POSE_TYPE
        for topic in wanted:
            if reader.info.topics[topic] != expected:
                raise BagError(f'bag {bag}: topic {topic} holds {reader.info.topics[topic]}, '
                               f'expected {expected}'
                               + ('' if source.rigid else f'{_rigid_hint(reader)}'))
        for m in reader.messages(wanted, fast_poses=True):
            if source.rigid:
                sel = select_bodies(m.msg, source.bodies)
                tally.add(sel)
                for role, pose in sel.poses.items():
                    data[role][0].append(sel.stamp_ns)
                    data[role][1].append(pose)
                if sel.poses:
                    frames.add(sel.frame_id)
                continue
            for role in ROLES:
                if m.topic == source.topics[role]:
                    data[role][0].append(m.msg.stamp_ns)
                    data[role][1].append(m.msg.pose)
            frames.add(m.msg.frame_id)
    ref = min((s[0] for s, _ in data.values() if s), default=0)
    tracks = []
    for role, (stamps, poses) in data.items():
        name = f'{source.rigid_bodies_topic} body {source.bodies[role]!r} ({role})' \
            if source.rigid else source.topics[role]
        if len(stamps) < 2:
            missing = tally.text(f'RigidBodies messages on {source.rigid_bodies_topic}')
            if missing:
                raise BagError(f'bag {bag}: {missing}: is the body named as the driver names '
                               'it (OptiTrack: the Motive ID)?')
            raise BagError(f'bag {bag}: {name} has {len(stamps)} pose(s); record a few '
                           'seconds of the object held still')
        tracks.append(PoseTrack((np.asarray(stamps) - ref) * 1e-9,
                                np.asarray(poses).reshape(-1, 7), name=name))
    return tracks[0], tracks[1], tuple(sorted(frames))


def _rigid_hint(reader: BagReader) -> str:
    """Where the bag holds RigidBodies, how to read them."""
    rigid = sorted(t for t, ty in reader.info.topics.items() if ty == RIGID_BODIES_TYPE)
    if not rigid:
        return ''
    return (f' (the bag holds mocap4r2 RigidBodies on {", ".join(rigid)}: name the bodies, '
            '--finger-body and --object-body, or a --setup cell with pose_source '
            'rigid_bodies)')


def _why(reader: BagReader, source: MocapSource) -> str:
    return 'the RigidBodies of the finger and object' if source.rigid else \
        'the finger and object poses' + _rigid_hint(reader)


def measure(finger: PoseTrack, obj: PoseTrack, orientation: Sequence[float] =
            IDENTITY_POSE[3:], frame_ids: tuple = ()) -> GraspPlaneResult:
    """Pair the tracks over their common span and measure; ValueError with too few pairs."""
    t0, t1 = max(finger.t[0], obj.t[0]), min(finger.t[-1], obj.t[-1])
    inside = (obj.t >= t0) & (obj.t <= t1)
    tq = obj.t[inside]
    if tq.size < MIN_PAIRS:
        raise ValueError(f'only {tq.size} object poses overlap the finger track in time '
                         f'(need {MIN_PAIRS}): record both rigid bodies together')
    pos, rot = finger.interpolate(tq)
    f = np.concatenate([pos, rot.as_quat()], axis=1)
    o = np.concatenate([obj.pos[inside], obj.quat[inside]], axis=1)
    rel = compose(invert(f), o)[:, :3]
    spread = float(np.max(np.linalg.norm(rel - np.median(rel, axis=0), axis=1)))
    pose = measure_grasp_plane(f, o, orientation, min_pairs=MIN_PAIRS)
    return GraspPlaneResult(pose, int(tq.size), float(tq[-1] - tq[0]), spread, frame_ids)


def grasp_plane_verdict(result: GraspPlaneResult,
                        max_spread_m: float = DEFAULT_MAX_SPREAD_M) -> Verdict:
    """FAIL when the object moved in the finger frame, or the streams' frames differ."""
    verdict = Verdict()
    if result.spread_m > max_spread_m:
        verdict.fail(f'the object moved: its position in the finger frame spread '
                     f'{result.spread_m * 1e3:.1f} mm (at most {max_spread_m * 1e3:.1f} mm): '
                     'record again with the object held still in the grasp')
    if len(result.frame_ids) > 1:
        verdict.fail(f'the poses are in different frames {list(result.frame_ids)}: both must '
                     'be in the mocap world frame')
    return verdict


def check_grasp_plane(bag, source: MocapSource, out,
                      max_spread_m: float = DEFAULT_MAX_SPREAD_M,
                      orientation: Sequence[float] = IDENTITY_POSE[3:]) -> int:
    """Run the check on ``bag`` with the poses of ``source``, print the result and the
    verdict; return the exit code."""
    finger, obj, frames = read_pose_tracks(bag, source)
    result = measure(finger, obj, orientation, frames)
    print(f'{result.pairs} pose pairs over {result.duration_s:.2f} s; object position spread '
          f'in the finger frame {result.spread_m * 1e3:.2f} mm', file=out)
    verdict = grasp_plane_verdict(result, max_spread_m)
    if verdict.ok:
        print('paste into the cell setup file:', file=out)
        print(result.setup_lines(), file=out)
    verdict.notes.append('the orientation is not measured here: it is the one given '
                         '(--orientation, default identity); aslip check grasp-axes '
                         'measures it')
    return verdict.report(out)
