"""aslip check grasp-plane on bags written with the package's bag writer: a still object gives
its offset in the finger frame as the setup line; a moving one fails."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from aslip_ros import cli, topics
from aslip_ros.data import bags
from aslip_ros.poses import compose

OFFSET = np.array([0.012, -0.003, 0.045])


def write_bag(path, slide_m_per_s=0.0, seconds=2.0, rate=100.0, seed=0):
    """Finger rotated and moving slowly in the world; the object at OFFSET in the finger frame
    (plus 0.2 mm of mocap noise), sliding along the finger's x at ``slide_m_per_s``."""
    rng = np.random.default_rng(seed)
    with bags.BagWriter(path, start_ns=1_700_000_000_000_000_000) as w:
        for k in range(int(seconds * rate)):
            t = k / rate
            q = Rotation.from_euler('zyx', [30 + 5 * t, 10, -5], degrees=True).as_quat()
            finger = np.concatenate([[0.4 + 0.01 * t, 0.1, 0.3], q])
            rel = OFFSET + [slide_m_per_s * t, 0, 0] + 2e-4 * rng.standard_normal(3)
            obj = compose(finger, np.concatenate([rel, [0, 0, 0, 1]]))
            w.write_pose('finger', t, finger)
            # The object's camera frames arrive 3 ms later: pairing interpolates the finger.
            w.write_pose('object', t + 0.003, obj)
    return path


def _setup_line(out):
    lines = out.splitlines()
    i = lines.index('mocap_bridge:')
    text = lines[i + 1]
    assert text.startswith('  grasp_plane_in_finger: [') and text.endswith(']')
    return [float(v) for v in text.split('[')[1].rstrip(']').split(',')]


def test_still_object_gives_its_offset_in_the_finger_frame(tmp_path, capsys):
    bag = write_bag(tmp_path / 'still')
    rc = cli.main(['check', 'grasp-plane', str(bag), '--finger-topic', topics.FINGER,
                   '--object-topic', topics.OBJECT])
    out = capsys.readouterr().out
    assert rc == 0, out
    pose = _setup_line(out)
    assert pose[:3] == pytest.approx(OFFSET, abs=1e-4)
    assert pose[3:] == [0.0, 0.0, 0.0, 1.0]
    assert out.splitlines()[-1] == 'verdict: OK'


def test_moving_object_fails_and_prints_no_setup_line(tmp_path, capsys):
    bag = write_bag(tmp_path / 'moving', slide_m_per_s=0.01)     # 2 cm over the recording
    rc = cli.main(['check', 'grasp-plane', str(bag)])
    out = capsys.readouterr().out
    assert rc == 1, out
    assert 'mocap_bridge:' not in out
    last = out.splitlines()[-1]
    assert last.startswith('verdict: FAIL: the object moved')
    spread_mm = float(last.split('spread ')[1].split(' mm')[0])
    assert spread_mm == pytest.approx(10.0, abs=1.0)     # half of the 2 cm slide


def test_a_bag_without_the_topics_is_refused_in_one_line(tmp_path, capsys):
    bag = write_bag(tmp_path / 'still')
    rc = cli.main(['check', 'grasp-plane', str(bag), '--object-topic', '/nothing'])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1 and 'has no topic /nothing' in err[0]


def test_the_printed_lines_load_as_a_cell_file(tmp_path, capsys):
    cell = pytest.importorskip('aslip_ros.cell')
    bag = write_bag(tmp_path / 'still')
    assert cli.main(['check', 'grasp-plane', str(bag)]) == 0
    out = capsys.readouterr().out.splitlines()
    i = out.index('mocap_bridge:')
    path = tmp_path / 'cell.yaml'
    path.write_text('\n'.join(out[i:i + 2]) + '\n')
    loaded = cell.load_cell(str(path)).get('mocap_bridge', 'grasp_plane_in_finger')
    assert loaded[:3] == pytest.approx(OFFSET, abs=1e-4)


# ------------------------------------------------- mocap4r2: the bodies of one RigidBodies

def write_rigid_bodies_bag(path, seconds=2.0, rate=100.0, seed=0, names=("1", "3", "5")):
    """The still grasp of :func:`write_bag` as mocap4r2's OptiTrack driver records it: one
    RigidBodies per camera frame on /rigid_bodies, frame ``map``, every body named by its
    Motive ID (1 a still marker set, 3 the finger, 5 the object; ``names`` those sent),
    received 3 ms after the stamp; no metadata (``ros2 bag record``)."""
    from test_data_export_rigid_bodies import RB, STILL, _rigid_bodies, _store
    store = _store()
    rng = np.random.default_rng(seed)
    start = 1_700_000_000_000_000_000
    with bags.BagWriter(path, store=store) as w:
        for k in range(int(seconds * rate)):
            t = k / rate
            q = Rotation.from_euler('zyx', [30 + 5 * t, 10, -5], degrees=True).as_quat()
            finger = np.concatenate([[0.4 + 0.01 * t, 0.1, 0.3], q])
            rel = OFFSET + 2e-4 * rng.standard_normal(3)
            obj = compose(finger, np.concatenate([rel, [0, 0, 0, 1]]))
            of = {"1": STILL, "3": finger, "5": obj}
            stamp = start + int(round(t * 1e9))
            w.write(topics.RIGID_BODIES, RB, _rigid_bodies(
                store, stamp, [(n, of[n]) for n in names]), stamp + 3_000_000)
    return path


def test_rigid_bodies_by_id_give_the_same_offset(tmp_path, capsys):
    bag = write_rigid_bodies_bag(tmp_path / 'still')
    rc = cli.main(['check', 'grasp-plane', str(bag), '--finger-body', '3',
                   '--object-body', '5'])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert _setup_line(out)[:3] == pytest.approx(OFFSET, abs=1e-4)
    assert out.splitlines()[-1] == 'verdict: OK'


def _rigid_cell(path, **keys):
    lines = ['mocap_bridge:', '  pose_source: rigid_bodies']
    lines += [f'  {key}: {value}' for key, value in keys.items()]
    path.write_text('\n'.join(lines) + '\n')
    return str(path)


def test_a_rigid_bodies_cell_needs_no_option(tmp_path, capsys):
    """The cell's own keys (pose_source rigid_bodies, bodies as numbers in YAML) choose the
    RigidBodies: the same command as a PoseStamped cell's."""
    bag = write_rigid_bodies_bag(tmp_path / 'still')
    cell = _rigid_cell(tmp_path / 'cell.yaml', finger_body=3, object_body=5)
    rc = cli.main(['check', 'grasp-plane', str(bag), '--setup', cell])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert _setup_line(out)[:3] == pytest.approx(OFFSET, abs=1e-4)


def test_a_body_the_messages_lack_is_named_with_those_present(tmp_path, capsys):
    bag = write_rigid_bodies_bag(tmp_path / 'still', seconds=0.5)
    cell = _rigid_cell(tmp_path / 'cell.yaml', finger_body=3, object_body=7)
    rc = cli.main(['check', 'grasp-plane', str(bag), '--setup', cell])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1, err
    assert "rigid body '7' (object) is in none of the 50 RigidBodies messages on " \
        "/rigid_bodies; bodies present: '1', '3', '5'" in err[0]


def test_a_rigid_bodies_bag_read_for_pose_topics_says_how_to_read_it(tmp_path, capsys):
    bag = write_rigid_bodies_bag(tmp_path / 'still', seconds=0.5)
    rc = cli.main(['check', 'grasp-plane', str(bag)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1, err
    assert 'the bag holds mocap4r2 RigidBodies on /rigid_bodies: name the bodies' in err[0]
    assert cli.main(['check', 'grasp-plane', str(bag), '--finger-body', '3']) == 1
    assert '--finger-body and --object-body go together' in capsys.readouterr().err
