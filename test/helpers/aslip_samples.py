"""Sample messages with every field set to a distinctive non-default value.

Shared by the plumbing tests and the child publisher process they start, so both sides
build the same expectation.
"""

from __future__ import annotations

import math

import numpy as np

# The public contract of the messages: these fields must exist.
REQUIRED_FIELDS = {
    "AudioFrame": {"header", "sample_rate", "channel_names", "first_sample_index", "data"},
    "SlipVector": {"header", "probability", "slipping", "threshold", "velocity", "speed",
                   "direction", "window_length"},
}


def audio_samples(n_frames: int = 480, n_channels: int = 4) -> np.ndarray:
    t = np.arange(n_frames)[:, None] / 48000.0
    ch = np.arange(n_channels)[None, :]
    return (0.5 * np.sin(2 * math.pi * (440.0 + 110.0 * ch) * t)).astype(np.float32)


def fill(msg, rng_seed: int = 7):
    """Set every field of an aslip_ros message to a distinctive value; return it."""
    name = type(msg).__name__
    msg.header.stamp.sec = 1_700_000_123
    msg.header.stamp.nanosec = 456_789_012
    if name == "AudioFrame":
        msg.header.frame_id = "aslip_gripper"
        msg.sample_rate = 44100.0
        msg.channel_names = ["left_front", "left_rear", "right_front", "right_rear"]
        msg.layout = "4mic"
        msg.first_sample_index = 2**40 + 12345
        msg.data = audio_samples().reshape(-1).tolist()
    elif name == "SlipVector":
        msg.header.frame_id = "aslip_grasp_plane"
        msg.probability = 0.875
        msg.slipping = True
        msg.threshold = 0.5
        msg.velocity.x = 0.0125
        msg.velocity.y = 0.0
        msg.velocity.z = -0.0375
        msg.speed = float(np.hypot(0.0125, 0.0375))
        msg.direction = float(np.arctan2(-0.0375, 0.0125))
        msg.direction_sigma = 0.25
        msg.angular_velocity = 0.75
        msg.angular_velocity_sigma = 0.125
        msg.window_length = 0.2
        msg.source = "aslip_cnn"
    else:
        raise ValueError(f"no sample for {name}")
    return msg


def to_plain(value):
    """Message -> nested plain Python (dicts, lists, floats) for comparison."""
    if hasattr(value, "get_fields_and_field_types"):
        return {k: to_plain(getattr(value, k)) for k in value.get_fields_and_field_types()}
    if isinstance(value, (list, tuple)) or hasattr(value, "tolist"):
        return [to_plain(v) for v in (value.tolist() if hasattr(value, "tolist") else value)]
    if isinstance(value, float):
        return float(np.float32(value))  # compare at float32 precision
    return value
