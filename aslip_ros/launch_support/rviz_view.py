"""The rviz view of one graph: config/aslip.rviz with the topics the graph really uses.

config/aslip.rviz names the contract's topics (aslip_ros/topics.py); a cell's motion capture
publishes on its driver's own (``/vrpn_mocap/aslip_finger/pose``), so rviz started with the
shipped file shows no finger, no object. :func:`write_view` writes the shipped view with the
graph's pose topics into ``$ROS_HOME/aslip_ros/rviz/`` (a name of its content, written
atomically: launches running side by side never read each other's half-written file), and
drops the TCP display where nothing joins ``link_base`` to ``world`` (hardware without the
cell's ``base_in_world``: mocap_bridge's ``publish_base_tf``) and the finger and object
pose displays where the graph has no PoseStamped for them (mocap4r2's RigidBodies: the TF
display shows both bodies), saying so, instead of a display rviz can only mark as broken.

ROS-free: the launch files call it (aslip_ros/launch_support/common.py).
"""

from __future__ import annotations

import copy
import hashlib
import os
from pathlib import Path
from typing import Mapping, Optional, Tuple

import yaml

from aslip_ros import frames, topics
from aslip_ros.util import write_text


def displays(doc: dict) -> list:
    """The display entries of an rviz config."""
    return doc["Visualization Manager"]["Displays"]


def display_topic(display: dict) -> Optional[str]:
    """The topic a display subscribes to, or None."""
    topic = display.get("Topic")
    return topic.get("Value") if isinstance(topic, dict) else None


def view(template: dict, renamed: Mapping[str, Optional[str]], tcp_placed: bool
         ) -> Tuple[dict, list]:
    """``(config, notes)``: ``template`` with each display topic renamed by ``renamed``
    (contract topic -> the graph's; None: no such topic, the display is left out), the fixed
    frame ``world``, and without the TCP display unless ``tcp_placed``."""
    doc = copy.deepcopy(template)
    notes, kept = [], []
    for d in displays(doc):
        topic = display_topic(d)
        if topic == topics.TCP and not tcp_placed:
            notes.append(f"the {d.get('Name', 'TCP')} display is left out: nothing publishes "
                         f"{frames.WORLD} -> {frames.BASE} (set the cell's mocap_bridge "
                         "base_in_world and publish_base_tf: true)")
            continue
        if topic in renamed and renamed[topic] is None:
            notes.append(f"the {d.get('Name', topic)} display is left out: the motion capture "
                         "publishes no PoseStamped for it (the TF display shows the body)")
            continue
        if topic in renamed:
            d["Topic"]["Value"] = renamed[topic]
        kept.append(d)
    doc["Visualization Manager"]["Displays"] = kept
    doc["Visualization Manager"]["Global Options"]["Fixed Frame"] = frames.WORLD
    return doc, notes


def view_dir(env: Mapping[str, str] = os.environ) -> Path:
    """Where written views go: ``$ROS_HOME/aslip_ros/rviz`` (``~/.ros`` by default)."""
    home = env.get("ROS_HOME") or os.path.join(os.path.expanduser("~"), ".ros")
    return Path(home) / "aslip_ros" / "rviz"


def write_view(template_path: str | os.PathLike, finger_topic: Optional[str],
               object_topic: Optional[str], tcp_placed: bool,
               env: Mapping[str, str] = os.environ) -> Tuple[Path, list]:
    """Write the view for a graph's PoseStamped topics (None: the graph has none for that
    body); returns ``(path, notes)``."""
    template = yaml.safe_load(Path(template_path).read_text())
    doc, notes = view(template, {topics.FINGER: finger_topic, topics.OBJECT: object_topic},
                      tcp_placed)
    text = yaml.safe_dump(doc, sort_keys=False)
    name = hashlib.sha1(text.encode()).hexdigest()[:12]
    path = view_dir(env) / f"aslip_{name}.rviz"
    write_text(path, text)
    return path, notes
