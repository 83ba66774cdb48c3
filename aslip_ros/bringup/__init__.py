"""Bring-up checks a lab runs once on a new cell (``aslip check <what>``).

Each check prints what it measured and one verdict line, ``verdict: OK`` or
``verdict: FAIL: <reason>``, and exits 0 or 1 accordingly (docs/bringup.md). The
measurements and verdicts are pure functions here; only :mod:`aslip_ros.nodes.mocap_check`
talks to ROS, and only ``aslip check mocap`` imports it.
"""
