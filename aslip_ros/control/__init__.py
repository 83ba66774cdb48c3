"""aslip_ros.control: ROS-free control logic (floor 1; imports numpy and scipy only).

- (the :class:`~aslip_ros.arm.Arm` protocol and :class:`~aslip_ros.arm.ArmError` are on floor
  0, :mod:`aslip_ros.arm`, shared with the scene's simulated arm and hw/)
- :mod:`.command`: :class:`~.command.VelocityCommand` and :func:`~.command.apply_command`.
- :mod:`.watchdog`: input staleness (default 100 ms).
- :mod:`.frames`: grasp plane <-> ``link_base`` transforms.
- :mod:`.slip_stop`: the wall-push task (stop on slip, report the stopping distance).
- :mod:`.slip_track`: follow the object along the predicted slip vector.
"""
