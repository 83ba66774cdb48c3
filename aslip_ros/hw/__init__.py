"""aslip_ros.hw: adapters for real hardware, without ROS.

- :mod:`.xarm`: :class:`~.xarm.XArmAdapter`, the xArm as a ``control.arm.Arm``.
- :mod:`.audio`: PortAudio capture (:class:`~.audio.SoundDeviceCapture`) and WAV replay.
- :mod:`.mocap`: NatNet rigid-body poses (:class:`~.mocap.NatNetMocap`).

The driver libraries (xarm-python-sdk, sounddevice, natnet) are imported lazily, inside
the adapters, so importing this package never needs them.
"""
