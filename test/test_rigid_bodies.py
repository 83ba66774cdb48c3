"""The one decoding of mocap4r2's RigidBodies (aslip_ros/rigid_bodies.py), ROS-free: bodies
picked by name or numeric ID, poses as sent, missing bodies named with those present."""

from __future__ import annotations

from types import SimpleNamespace as NS

import numpy as np
import pytest

from aslip_ros.rigid_bodies import BodyTally, body_key, missing_text, select_bodies


def rigid_bodies(k: int, names, frame_id: str = "map"):
    """A RigidBodies-shaped message (the fields rclpy's and rosbags' messages share): frame
    k stamped k * 10 ms after 1 s; body ``n``'s pose is (n, 2n, 3n) with a turn about z."""
    def body(name):
        n = float(int(name)) if name.isdigit() else 9.0
        return NS(rigid_body_name=name, markers=[], pose=NS(
            position=NS(x=n, y=2 * n, z=3 * n), orientation=NS(x=0.0, y=0.0, z=0.6, w=0.8)))
    return NS(header=NS(stamp=NS(sec=1, nanosec=k * 10_000_000), frame_id=frame_id),
              frame_number=k, rigidbodies=[body(str(n)) for n in names])


def test_bodies_are_picked_by_name_or_id_however_written():
    assert body_key(3) == body_key("3") == body_key(" 03 ") == "3"
    assert body_key("finger") == "finger" and body_key("Finger") != "finger"
    sel = select_bodies(rigid_bodies(2, ["1", "3", "5"]), {"finger": 3, "object": "005"})
    assert sel.stamp_ns == 1_020_000_000 and sel.frame_id == "map" and sel.frame_number == 2
    np.testing.assert_array_equal(sel.poses["finger"], [3, 6, 9, 0, 0, 0.6, 0.8])
    np.testing.assert_array_equal(sel.poses["object"], [5, 10, 15, 0, 0, 0.6, 0.8])
    assert sel.missing == () and sel.missing_text == "" and sel.present == ("1", "3", "5")
    named = select_bodies(rigid_bodies(0, ["finger_rb", "3"]), {"finger": "finger_rb"})
    assert named.poses["finger"][0] == 9.0


def test_a_missing_body_is_named_with_the_bodies_present():
    sel = select_bodies(rigid_bodies(0, ["1", "3"]), {"finger": "3", "object": "5"})
    assert list(sel.poses) == ["finger"] and sel.missing == ("object",)
    assert sel.missing_text == ("rigid body '5' (object) is not in the RigidBodies message; "
                                "bodies present: '1', '3'")
    none = select_bodies(rigid_bodies(0, []), {"finger": "3", "object": "5"})
    assert none.missing_text == ("rigid body '3' (finger) and '5' (object) are not in the "
                                 "RigidBodies message; bodies present: none")
    assert missing_text({"finger": "3"}, (), ["3"]) == ""
    with pytest.raises(ValueError, match="no rigid body named for the object"):
        select_bodies(rigid_bodies(0, ["1"]), {"finger": "3", "object": " "})


def test_the_tally_counts_messages_without_a_body():
    tally = BodyTally({"finger": "3", "object": "5"})
    for k in range(10):
        tally.add(select_bodies(rigid_bodies(k, ["1", "3"] if k < 4 else ["5", "3", "1"]),
                                tally.bodies))
    assert tally.messages == 10 and tally.missing == {"object": 4}
    assert tally.text() == ("rigid body '5' (object) is missing from 4 of the 10 RigidBodies "
                            "messages; bodies present: '1', '3', '5'")
    assert BodyTally({"finger": "3"}).text() == ""
