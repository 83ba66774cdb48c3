"""NatNet adapter with a fake client: pose conversion, filtering, staleness, errors."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from aslip_ros.hw.mocap import MocapError, NatNetMocap


class FakeEvent:
    def __init__(self):
        self.handlers = []

    def call(self, *args):
        for h in self.handlers:
            h(*args)


class FakeClient:
    def __init__(self, fail=None):
        self.on_data_frame_received_event = FakeEvent()
        self.fail = fail
        self.calls = []

    def connect(self, timeout=5.0):
        self.calls.append(('connect', timeout))
        if self.fail:
            raise self.fail

    def run_async(self):
        self.calls.append(('run_async',))

    def shutdown(self):
        self.calls.append(('shutdown',))

    def emit(self, number, bodies, timestamp=1.5):
        frame = SimpleNamespace(prefix=SimpleNamespace(frame_number=number),
                                suffix=SimpleNamespace(timestamp=timestamp),
                                rigid_bodies=[SimpleNamespace(id_num=i, pos=p, rot=q,
                                                              tracking_valid=v)
                                              for i, p, q, v in bodies])
        self.on_data_frame_received_event.call(frame)


def make(up_axis='y', **kw):
    client = FakeClient(**kw)
    mocap = NatNetMocap('10.0.0.2', '10.0.0.3', {'finger': 1, 'object': 2}, up_axis=up_axis,
                        client_factory=lambda *a: client, host_clock=lambda: 42.0)
    return mocap, client


def test_start_registers_and_runs():
    mocap, client = make()
    mocap.start()
    assert [c[0] for c in client.calls] == ['connect', 'run_async']
    mocap.stop()
    assert client.calls[-1] == ('shutdown',)


def test_y_up_converted_to_z_up():
    mocap, client = make('y')
    mocap.start()
    q = Rotation.from_euler('y', 30, degrees=True).as_quat()   # yaw about Motive's up
    client.emit(7, [(1, (0.1, 0.2, 0.3), q, True), (9, (0, 0, 0), (0, 0, 0, 1), True)])
    frame = mocap.read(0.1)
    assert frame.frame_number == 7 and frame.host_time == 42.0 and frame.server_time == 1.5
    assert set(frame.bodies) == {'finger'}                    # id 9 not configured
    pose = frame.bodies['finger'].pose
    assert np.allclose(pose[:3], [0.1, -0.3, 0.2])            # y up -> z up
    # The body frame keeps its physical axes: its local y (Motive's up) is world z, and a
    # 30 degree turn about Motive's up axis turns its local x by 30 degrees about world z.
    r = Rotation.from_quat(pose[3:])
    assert np.allclose(r.apply([0, 1, 0]), [0, 0, 1], atol=1e-9)
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    assert np.allclose(r.apply([1, 0, 0]), [c, s, 0], atol=1e-9)
    assert np.allclose(mocap.latest('finger').pose, pose)
    assert mocap.latest_host_time('finger') == 42.0
    assert mocap.latest('object') is None


def test_z_up_passthrough():
    mocap, client = make('z')
    mocap.start()
    client.emit(1, [(2, (0.1, 0.2, 0.3), (0, 0, 0, 1), True)])
    assert np.allclose(mocap.latest('object').pose, [0.1, 0.2, 0.3, 0, 0, 0, 1])


def test_lost_tracking_and_garbage_keep_last_good_pose():
    mocap, client = make('z')
    mocap.start()
    client.emit(1, [(1, (0.1, 0, 0), (0, 0, 0, 1), True)])
    client.emit(2, [(1, (9, 9, 9), (0, 0, 0, 1), False)])
    client.emit(3, [(1, (np.nan, 0, 0), (0, 0, 0, 1), True)])
    client.emit(4, [(1, (0, 0, 0), (0, 0, 0, 0), True)])
    assert np.allclose(mocap.latest('finger').pose[:3], [0.1, 0, 0])
    frames = [mocap.read(0) for _ in range(4)]
    assert [f.bodies['finger'].tracking_valid for f in frames] == [True, False, False, False]
    # A malformed frame is counted, not raised into the client's thread.
    mocap._on_frame(SimpleNamespace(rigid_bodies=[None]))
    assert mocap.frames_rejected == 1


def test_queue_overflow_counted():
    client = FakeClient()
    mocap = NatNetMocap('a', 'b', {'finger': 1}, queue_frames=2,
                        client_factory=lambda *a: client)
    mocap.start()
    for i in range(5):
        client.emit(i, [(1, (0, 0, 0), (0, 0, 0, 1), True)])
    assert mocap.frames_received == 5 and mocap.frames_dropped == 3
    assert mocap.read(0).frame_number == 0


def test_unreachable_server_is_mocap_error():
    mocap, _ = make(fail=TimeoutError())
    with pytest.raises(MocapError):
        mocap.start()


@pytest.mark.parametrize('kwargs', [dict(up_axis='x'), dict(rigid_bodies={}),
                                    dict(rigid_bodies={'a': 1, 'b': 1}),
                                    dict(queue_frames=0)])
def test_bad_config(kwargs):
    args = dict(server_ip='a', local_ip='b', rigid_bodies={'finger': 1})
    args.update(kwargs)
    with pytest.raises(ValueError):
        NatNetMocap(**args)
