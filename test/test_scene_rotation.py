"""Rotational slip in the scene (issue #21): physics, kinematics, scenarios, simulate."""

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from aslip_ros import cli
from aslip_ros.data import bags
from aslip_ros.scene import Acoustics, World, scenarios
from aslip_ros.scene.layouts import get_layout, get_object, get_pad
from aslip_ros.scene.physics import Synth
from aslip_ros.slip import ROTATION_EPSILON_RAD_S as ROTATING_RAD_S
from helpers.before_rotation import tree_before

FS = 48000
ROOT = Path(__file__).resolve().parents[1]

#: Renders with whichever aslip_ros comes first on the path; writes an npz.
_REFERENCE = textwrap.dedent("""
    import sys
    import numpy as np
    from aslip_ros.scene import World, scenarios
    from aslip_ros.scene.layouts import get_layout, get_object, get_pad
    from aslip_ros.scene.physics import Acoustics, Synth

    out = {}
    for seed, layout, pad in ((0, "4mic", "textured"), (3, "1mic", "smooth")):
        syn = Synth(get_layout(layout), get_pad(pad), get_object("chips_can"), Acoustics(),
                    48000.0, seed)
        rng = np.random.default_rng(seed)
        blocks = []
        for k in range(4):
            n = 2400
            v = np.tile(rng.uniform(-0.05, 0.05, 2), (n, 1)) * (k % 3 != 0)
            vt = np.tile(rng.uniform(-0.05, 0.05, 3), (n, 1)) * (k % 2)
            blocks.append(syn.render(k * n, v, vt, np.full(n, 0.5 * (k % 2))))
        out[f"synth_{seed}"] = np.concatenate(blocks)
    for name, scn in (("ext", scenarios.external_induced(seed=11, duration_s=1.5)),
                      ("rob", scenarios.robot_induced(seed=14, duration_s=1.0))):
        chunks = list(World(scn).stream(480))
        out[name + "_audio"] = np.concatenate([c.audio for c in chunks])
        out[name + "_v"] = np.concatenate([c.v_rel for c in chunks])
        out[name + "_object"] = np.array([m.object_pose for c in chunks for m in c.mocap])
    world = World(scenarios.wall_push(seed=17, wall_distance_m=0.01))
    world.arm.connect()
    world.arm.enable_velocity_mode()
    chunks = []
    for _ in range(60):
        world.arm.send_velocity(0.04 * world.wall_normal(), 0.05)
        chunks.append(world.step(480))
    out["wall_audio"] = np.concatenate([c.audio for c in chunks])
    out["wall_object"] = np.array([m.object_pose for c in chunks for m in c.mocap])
    np.savez(sys.argv[1], **out)
""")


def _version_3_tree(tmp_path: Path) -> Path:
    """The package as of scene version 3, extracted from git (skips where there is none)."""
    return tree_before("aslip_ros", tmp_path / "v3")


def _render(tmp_path: Path, pythonpath: Path, name: str) -> dict:
    script = tmp_path / "reference.py"
    script.write_text(_REFERENCE)
    out = tmp_path / f"{name}.npz"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(pythonpath)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep)
                             if p]))
    subprocess.run([sys.executable, str(script), str(out)], env=env, cwd=tmp_path,
                   check=True, timeout=120)
    return dict(np.load(out))


def test_without_rotation_the_scene_renders_exactly_what_version_3_rendered(tmp_path):
    old = _render(tmp_path, _version_3_tree(tmp_path), "v3")
    new = _render(tmp_path, ROOT, "v4")
    assert set(old) == set(new)
    for key in old:
        assert np.array_equal(old[key], new[key]), key


def test_a_zero_rotation_is_the_same_as_none():
    def render(w_rel):
        syn = Synth(get_layout("4mic"), get_pad("textured"), get_object("chips_can"),
                    Acoustics(), FS, 5)
        v = np.tile([0.03, -0.01], (2400, 1))
        return syn.render(0, v, np.zeros((2400, 3)), np.zeros(2400), w_rel=w_rel)
    assert np.array_equal(render(None), render(np.zeros(2400)))


def test_a_pure_rotation_moves_front_and_back_of_a_finger_oppositely():
    syn = Synth(get_layout("4mic"), get_pad("textured"), get_object("chips_can"),
                Acoustics(), FS, 0)
    names = get_layout("4mic").channel_names
    front, back = names.index("left_front_top"), names.index("left_rear_bottom")
    local = syn.local_velocities(np.zeros((3, 2)), np.full(3, 2.0))
    assert local.shape == (3, 4, 2)
    assert np.allclose(local[:, front], -local[:, back])            # opposite directions
    assert np.allclose(local[0, front], [2.0 * 9e-3, -2.0 * 9e-3])   # w x r at (9, 9) mm
    # A translation moves every point alike.
    same = syn.local_velocities(np.tile([0.01, 0.02], (3, 1)), np.zeros(3))
    assert np.allclose(same, [0.01, 0.02])


def _rms(layout: str, w: float, acoustics: Acoustics = Acoustics()) -> np.ndarray:
    syn = Synth(get_layout(layout), get_pad("textured"), get_object("chips_can"), acoustics,
                FS, 2)
    n = 9600
    audio = syn.render(0, np.zeros((n, 2)), np.zeros((n, 3)), np.zeros(n),
                       w_rel=np.full(n, w))
    return np.sqrt(np.mean(audio[2400:] ** 2, axis=0))


def test_a_centred_microphone_still_hears_a_rotation():
    quiet = _rms("1mic", 0.0)
    turning = _rms("1mic", 2.0)
    assert turning[0] > 4.0 * quiet[0]
    # It hears the patch around it: with a point microphone (no heard radius) the pad
    # centre does not move and it hears nothing.
    point = _rms("1mic", 2.0, Acoustics(heard_radius_m=0.0))
    assert point[0] == pytest.approx(quiet[0], rel=0.05)
    # The corner microphones sit under faster-moving pad and hear it louder.
    assert np.all(_rms("4mic", 2.0) > turning[0])


def _mocap_angle(chunks) -> tuple[np.ndarray, np.ndarray]:
    """Object angle relative to the finger about grasp-plane y, from the mocap quaternions."""
    t, angle = [], []
    for c in chunks:
        for m in c.mocap:
            rel = Rotation.from_quat(m.finger_pose[3:]).inv() * Rotation.from_quat(
                m.object_pose[3:])
            mat = rel.as_matrix()
            assert abs(mat[1, 1] - 1.0) < 1e-9          # a turn about y only
            t.append(m.t)
            angle.append(np.arctan2(mat[0, 2], mat[0, 0]))
    return np.array(t), np.unwrap(angle)


def test_mocap_orientation_integrates_the_true_angular_velocity():
    scn = scenarios.scripted(seed=1, segments=[(0.2, 1.2, 0.0, 0.0, 1.5),
                                               (1.4, 2.0, 0.01, 0.0, -2.0)],
                             duration_s=2.5, mocap_drop_prob=0.0)
    world = World(scn, record=True)
    chunks = list(world.stream(480))
    w = np.concatenate([c.w_rel for c in chunks])
    assert w[int(0.5 * FS)] == 1.5 and w[int(1.6 * FS)] == -2.0 and w[int(1.3 * FS)] == 0.0
    assert world.angle_turned() == pytest.approx(1.5 * 1.0 - 2.0 * 0.6, abs=1e-3)
    assert world.rotation_onset_time == pytest.approx(0.2, abs=1.0 / FS)
    t, angle = _mocap_angle(chunks)
    traj = world.trajectory()
    assert np.allclose(angle, traj["angle"][:len(angle)], atol=1e-9)
    assert np.allclose(angle, np.cumsum(w)[np.round(t * FS).astype(int)] / FS, atol=1e-3)
    assert np.allclose(traj["w_rel"][(traj["t"] > 0.3) & (traj["t"] < 1.1)], 1.5)
    # A pure turn about the pad centre leaves the object origin there.
    assert np.abs(traj["rel"][traj["t"] < 1.3]).max() < 1e-12


def test_the_object_origin_follows_the_turn():
    """dr/dt = v_c + w x r: an object off the grasp centre swings about it as it turns, and
    its velocity at the pad centre (the label) stays v_c."""
    scn = scenarios.scripted(seed=2, segments=[(0.0, 0.5, 0.02, 0.0),
                                               (1.0, 1.5, 0.0, 0.0, 2.0 * np.pi)],
                             duration_s=2.0, mocap_drop_prob=0.0)
    world = World(scn, record=True)
    chunks = list(world.stream(480))
    # 10 mm along +x, then half a turn about the pad centre: now 10 mm along -x.
    assert world.relative_xz() == pytest.approx([-0.01, 0.0], abs=1e-4)
    assert world.angle_turned() == pytest.approx(np.pi, abs=1e-3)
    assert not np.any(np.concatenate([c.v_rel for c in chunks])[int(0.6 * FS):])


def test_twist_fraction_zero_is_the_scene_without_twists_and_twists_turn():
    base = scenarios.external_induced(seed=8, duration_s=6.0)
    assert base.twist_fraction == 0.0
    plain = [c.w_rel for c in World(base).stream(4800)]
    assert not np.any(np.concatenate(plain))
    chunks = list(World(base.with_(twist_fraction=1.0)).stream(4800))
    w = np.concatenate([c.w_rel for c in chunks])
    v = np.hypot(*np.concatenate([c.v_rel for c in chunks]).T)
    assert np.abs(w).max() > ROTATING_RAD_S and np.abs(w).max() <= 6.0
    assert np.any((np.abs(w) > ROTATING_RAD_S) & (v == 0.0))        # pure twists
    assert np.any((np.abs(w) > ROTATING_RAD_S) & (v > 5e-3))        # twists with the push
    with pytest.raises(ValueError, match="twist_fraction"):
        base.with_(twist_fraction=1.5)


def test_gravity_pivot_turns_the_object_both_ways_with_little_slide():
    scn = scenarios.gravity_pivot(seed=4, duration_s=10.0)
    assert scn.induced == "external" and scn.kind == "gravity_pivot"
    chunks = list(World(scn).stream(9600))                  # 200 ms windows
    w = np.array([c.w_rel.mean() for c in chunks])
    v = np.array([np.hypot(*c.v_rel.mean(axis=0)) for c in chunks])
    turning = np.abs(w) > ROTATING_RAD_S
    assert 3 <= turning.sum() <= 0.6 * len(w)
    assert np.any(w > ROTATING_RAD_S) and np.any(w < -ROTATING_RAD_S)  # gravity, then a hand
    assert np.abs(np.concatenate([c.w_rel for c in chunks])).max() < 8.0
    slide = np.concatenate([c.v_rel for c in chunks])
    assert np.all(slide[:, 0] == 0.0) and np.abs(slide[:, 1]).max() > 0.0   # down, a little
    assert np.mean(v[turning] > 5e-3) < 0.5                 # the turn dominates
    # With the arm moving: the same turns (the agent's draws), heard while the arm wanders.
    moving = list(World(scenarios.gravity_pivot(seed=4, duration_s=10.0,
                                                condition="robot_moving")).stream(9600))
    np.testing.assert_array_equal(np.concatenate([c.w_rel for c in moving]),
                                  np.concatenate([c.w_rel for c in chunks]))

    def tcp_travel(cs):
        xyz = np.array([pose[:3] for c in cs for _, pose in c.tcp])
        return float(np.linalg.norm(xyz - xyz[0], axis=1).max())
    assert tcp_travel(chunks) == 0.0 and tcp_travel(moving) > 0.01


def _ready(world):
    world.arm.connect()
    world.arm.enable_velocity_mode()
    return world.arm


def test_the_pivoting_wall_push_turns_instead_of_sliding_and_stops_with_the_arm():
    scn = scenarios.wall_push(seed=2, push_dir_xz=(0.0, -1.0), pivot_lever_m=0.05,
                              wall_distance_m=0.01)
    assert scn.pivots and scenarios.wall_push(seed=2).pivot_lever_m == 0.0
    world = World(scn)
    arm = _ready(world)
    n = world.wall_normal()
    for _ in range(60):                                       # 0.6 s at 40 mm/s: 24 mm
        arm.send_velocity(0.04 * n, 0.05)
        chunk = world.step(480)
    assert world.wall_contact_time < world.rotation_onset_time < world.wall_contact_time + 0.05
    assert world.slip_onset_time is None
    assert np.abs(world.relative_xz()).max() < 1e-9           # turned, not slid
    # The contact point (lever L, object length a below the pad centre) swings back by the
    # arm's travel beyond the contact, less the compliance at which the wall's torque (its
    # force times the contact point's moment arm, L at first) reaches the torsional friction.
    u, lever, a = -world.angle_turned(), 0.05, get_object("chips_can").length_m
    arm_now = a * np.sin(u) + lever * np.cos(u)
    travel = (world.tcp_pose()[:3] - world.wall_contact_tcp_position) @ n
    slack = scn.torsional_friction_nm / (arm_now * scn.wall_stiffness_n_m)
    assert a * (1 - np.cos(u)) + lever * np.sin(u) == pytest.approx(travel - slack, abs=5e-5)
    assert np.degrees(u) > 8.0
    # It turns at the arm's speed over that moment arm (v / L at first).
    assert chunk.w_rel[-1] == pytest.approx(-0.04 / arm_now, rel=0.02)
    arm.stop()
    for _ in range(20):                                       # the lag settles (10 tau)
        world.step(480)
    stopped = world.angle_turned()
    for _ in range(30):
        chunk = world.step(480)
    # Still only what the lag's exp(-10) of 40 mm/s adds, at most a micro-radian.
    assert world.angle_turned() == pytest.approx(stopped, abs=1e-6)
    assert np.abs(chunk.w_rel).max() < 1e-4
    for _ in range(30):                                        # backing off: friction holds
        arm.send_velocity(-0.04 * n, 0.05)
        world.step(480)
    assert world.angle_turned() == pytest.approx(stopped, abs=1e-6)


def test_a_short_lever_still_slides():
    """Below 2/3 of the contact radius the force beats sliding friction first."""
    scn = scenarios.wall_push(seed=2, push_dir_xz=(0.0, -1.0), pivot_lever_m=0.005,
                              wall_distance_m=0.0)
    assert not scn.pivots
    world = World(scn)
    arm = _ready(world)
    for _ in range(40):
        arm.send_velocity(0.04 * world.wall_normal(), 0.05)
        world.step(480)
    assert world.angle_turned() == 0.0 and world.relative_xz()[1] > 5e-3


def test_scripted_segments_and_scenario_checks():
    assert scenarios.scripted(0, [(0, 1, 0.0, 0.0, 1.0)]).script[0][4] == 1.0
    with pytest.raises(ValueError, match="wy"):
        scenarios.scripted(0, [(0, 1, 0.0, 0.0, 1.0, 2.0)])
    with pytest.raises(ValueError, match="pivot_lever_m"):
        scenarios.wall_push(seed=0, pivot_lever_m=-0.1)
    with pytest.raises(ValueError, match="contact_radius_m"):
        scenarios.wall_push(seed=0, contact_radius_m=0.0)
    with pytest.raises(ValueError, match="heard_radius_m"):
        Acoustics(heard_radius_m=-1.0).validate()


def test_simulate_records_gravity_pivot_and_twists(tmp_path, capsys):
    out = tmp_path / "bags"
    args = ["simulate", "--trials", "1", "--duration", "0.5", "--layout", "1mic",
            "--no-progress", "-o"]
    assert cli.main(args + [str(out / "pivot"), "--kind", "pivot"]) == 0
    (bag,) = bags.find_bags([out / "pivot"])
    with bags.BagReader(bag) as r:
        assert r.metadata["scenario"] == "gravity_pivot" and r.metadata["scene_version"] == 4
    assert bag.name.startswith("piv-")
    assert cli.main(args + [str(out / "ext"), "--kind", "external",
                            "--twist-fraction", "0.5"]) == 0
    (bag,) = bags.find_bags([out / "ext"])
    with bags.BagReader(bag) as r:
        assert r.metadata["twist_fraction"] == 0.5
    assert cli.main(args + [str(out / "rob"), "--kind", "robot",
                            "--twist-fraction", "0.5"]) == 1
    assert "external only" in capsys.readouterr().err
