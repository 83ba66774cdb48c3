"""Per-grasp microphone calibration (``grasp``: the state and its constants; ``frames``: which
audio feeds it, offline and live) and calibrated outputs (``output``: threshold, direction
sigma)."""
