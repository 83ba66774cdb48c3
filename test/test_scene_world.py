"""Streaming, determinism, sensors and analytically known motion of the simulated scene."""

import numpy as np
import pytest

from aslip_ros.scene import World, scenarios
from aslip_ros.scene.layouts import yaw_rotation


def _collect(world, block):
    audio, mocap, tcp, v = [], [], [], []
    for ch in world.stream(block_frames=block):
        audio.append(ch.audio)
        mocap.extend(ch.mocap)
        tcp.extend(ch.tcp)
        v.append(ch.v_rel)
    return np.concatenate(audio), mocap, tcp, np.concatenate(v)


def test_same_seed_same_stream_other_seed_differs():
    a = _collect(World(scenarios.external_induced(seed=5, duration_s=2.0)), 480)
    b = _collect(World(scenarios.external_induced(seed=5, duration_s=2.0)), 480)
    c = _collect(World(scenarios.external_induced(seed=6, duration_s=2.0)), 480)
    assert np.array_equal(a[0], b[0])
    assert [m.t for m in a[1]] == [m.t for m in b[1]]
    assert np.array_equal(a[1][10].object_pose, b[1][10].object_pose)
    assert not np.allclose(a[0], c[0])


def test_output_does_not_depend_on_block_size():
    scn = scenarios.robot_induced(seed=2, duration_s=1.5)
    a = _collect(World(scn), 480)
    b = _collect(World(scn), 1001)
    assert a[0].shape == b[0].shape
    assert np.allclose(a[0], b[0], atol=1e-5)
    assert np.allclose(a[3], b[3])
    assert [m.t for m in a[1]] == [m.t for m in b[1]]


def test_chunk_shapes_metadata_and_rates():
    scn = scenarios.external_induced(seed=1, layout="2mic_corners", duration_s=2.0,
                                     sample_rate=44100.0, mocap_rate_hz=100.0)
    world = World(scn)
    meta = world.metadata()
    assert meta["channel_names"] == ["left_front_top", "right_rear_bottom"]
    assert meta["sample_rate"] == 44100.0 and meta["induced"] == "external"
    assert meta["seed"] == 1 and meta["trial_id"] == "ext-chips_can-0001"
    first = next(iter(world.stream(block_frames=441)))
    assert first.audio.shape == (441, 2) and first.audio.dtype == np.float32
    audio, mocap, tcp, _ = _collect(World(scn), 441)
    assert audio.shape == (88200, 2)
    assert 190 <= len(mocap) <= 200                       # 100 Hz, a few dropped
    assert len(tcp) == 200                                # 100 Hz robot state
    dt = np.diff([m.t for m in mocap])
    assert np.all(dt > 0) and np.min(dt) == pytest.approx(0.01, abs=1e-4)


def test_mocap_latency_delays_delivery():
    scn = scenarios.scripted(seed=0, segments=[], duration_s=0.5, mocap_latency_s=0.02,
                             mocap_drop_prob=0.0)
    for ch in World(scn).stream(block_frames=48):
        for m in ch.mocap:
            assert ch.t0 + 48 / 48000 > m.t + 0.02 - 1e-9   # delivered after capture + lag
            assert m.t + 0.02 >= ch.t0 - 1e-9


def test_pure_x_slip_known_speed():
    v = 0.02
    scn = scenarios.scripted(seed=3, segments=[(0.5, 1.5, v, 0.0)], duration_s=2.0,
                             mocap_noise_m=0.0, mocap_drop_prob=0.0)
    world = World(scn)
    audio, mocap, tcp, v_rel = _collect(world, 480)
    fs = 48000
    assert np.allclose(v_rel[int(0.6 * fs):int(1.4 * fs)], [v, 0.0])
    assert np.allclose(v_rel[:int(0.49 * fs)], 0.0) and np.allclose(v_rel[-1000:], 0.0)
    # Mocap: object relative to finger, expressed in the grasp plane, moves +x at v.
    rot = yaw_rotation(scn.yaw_rad)
    rel = np.array([rot.T @ (m.object_pose[:3] - m.finger_pose[:3]) for m in mocap])
    t = np.array([m.t for m in mocap])
    sel = (t > 0.6) & (t < 1.4)
    vel = np.polyfit(t[sel], rel[sel], 1)[0]
    assert vel == pytest.approx([v, 0.0, 0.0], abs=1e-6)
    assert rel[-1, 0] - rel[0, 0] == pytest.approx(v * 1.0, abs=1e-4)   # 20 mm in 1 s
    # The finger (gripper) itself does not move; the quaternion is the grasp plane's.
    assert np.ptp([m.finger_pose[:3] for m in mocap], axis=0) == pytest.approx(0, abs=1e-12)
    q = mocap[0].finger_pose[3:]
    assert q == pytest.approx([0, 0, np.sin(scn.yaw_rad / 2), np.cos(scn.yaw_rad / 2)])
    # Slip is louder than rest.
    slip_rms = np.sqrt(np.mean(audio[int(0.6 * fs):int(1.4 * fs)] ** 2))
    rest_rms = np.sqrt(np.mean(audio[:int(0.45 * fs)] ** 2))
    assert slip_rms > 3 * rest_rms


def test_robot_induced_labels_match_robot_state():
    scn = scenarios.robot_induced(seed=4, duration_s=4.0)
    world = World(scn)
    _, mocap, tcp, v_rel = _collect(world, 4800)
    rot = yaw_rotation(scn.yaw_rad)
    t = np.array([s[0] for s in tcp])
    p = np.array([s[1][:3] for s in tcp])
    v_tcp = np.gradient(p, t, axis=0) @ rot                 # in the grasp plane
    fs = 48000
    truth = v_rel[(t * fs).astype(int)]
    assert np.abs(v_tcp[:, 1]).max() < 1e-9                # sweeps stay in the plane
    assert np.allclose(-v_tcp[:, [0, 2]], truth, atol=2e-3)
    obj = np.array([m.object_pose[:3] for m in mocap])
    assert np.ptp(obj, axis=0).max() < 2e-3                 # the probe stands still
    assert np.abs(v_rel).max() > 0.005                      # and slip does happen


def test_scenarios_cover_slow_and_fast_slip_with_rest():
    speeds = []
    for seed in range(3):
        world = World(scenarios.external_induced(seed=seed, duration_s=30.0,
                                                 sample_rate=8000.0))
        speeds.append(np.concatenate([np.hypot(*c.v_rel[::40].T)
                                      for c in world.stream(8000)]))
    s = np.concatenate(speeds)
    assert 0.4 < np.mean(s < 1e-4) < 0.9                    # plenty of no-slip time
    assert np.mean((s > 1e-3) & (s < 8e-3)) > 0.03          # slow slip near a few mm/s
    assert s.max() > 0.05 and s.max() <= 0.1 + 1e-9


def test_external_pushes_slip_in_about_a_third_of_the_windows():
    """Detection accuracy means something only if "never slipping" scores well below it."""
    share = []
    for seed in range(8):
        scn = scenarios.external_induced(seed=seed, duration_s=30.0)
        push, _ = scenarios.agent_pushes(scn, np.random.default_rng(seed))
        t = np.arange(0.0, 30.0, 1e-3)
        x = np.cumsum(push.evaluate(t), axis=0) * 1e-3        # displacement [m]
        d = np.hypot(*(x[200::100] - x[:-200:100]).T)          # per 200 ms window, 100 ms hop
        share.append(np.mean(d > 1e-3))                         # > 5 mm/s on average
    assert 0.25 < np.mean(share) < 0.45


def test_robot_noise_only_when_arm_moves():
    kw = dict(seed=7, duration_s=3.0, layout="1mic")
    quiet = _collect(World(scenarios.external_induced(condition="robot_off", **kw)), 4800)
    moving = _collect(World(scenarios.external_induced(condition="robot_moving", **kw)), 4800)
    diff = moving[0] - quiet[0]
    assert np.abs(diff).max() > 1e-3
    tcp = np.array([s[1][:3] for s in moving[2]])
    still = np.all(np.abs(np.diff(tcp, axis=0)) < 1e-9, axis=1)
    idx = (np.array([s[0] for s in moving[2]])[1:][still] * 48000).astype(int)
    assert np.abs(diff[idx[idx < len(diff)]]).max() < 1e-6   # silent when still


def test_a_commanded_arm_sweeps_across_the_still_probe():
    """robot_induced with commanded_arm (a cell's robot_sweeps): the arm moves only as
    commanded and the slip is minus its in-plane motion; without the flag commands are
    refused (the scene drives its own sweeps)."""
    from dataclasses import replace

    import numpy as np
    import pytest

    from aslip_ros.arm import ArmError
    from aslip_ros.scene import World, scenarios
    scn = scenarios.robot_induced(seed=3, duration_s=None)
    own = World(scn)
    own.arm.connect(), own.arm.enable_velocity_mode()
    with pytest.raises(ArmError, match="drive the arm themselves"):
        own.arm.send_velocity(np.array([0.01, 0.0, 0.0]), 0.1)
    world = World(replace(scn, commanded_arm=True))
    world.arm.connect(), world.arm.enable_velocity_mode()
    still = world.step(4800)
    assert np.abs(still.v_rel).max() == 0.0          # nothing moves until commanded
    start = world.tcp_pose()[:3].copy()
    along = yaw_rotation(scn.yaw_rad)[:, 0]          # the grasp plane's x in the world
    for _ in range(50):
        world.arm.send_velocity(0.02 * along, 0.1)
        chunk = world.step(480)
    moved = world.tcp_pose()[:3] - start
    assert moved @ along == pytest.approx(0.02 * 0.5, abs=1.5e-3)
    assert np.linalg.norm(moved - (moved @ along) * along) < 1e-9
    assert chunk.v_rel[-1] == pytest.approx([-0.02, 0.0], abs=1e-4)
    # Every stop command is logged at its scene time (the demo's slip-onset-to-stop).
    assert world.arm.stop_times == []
    world.arm.stop()
    assert world.arm.stop_times == [pytest.approx(world.t)]
