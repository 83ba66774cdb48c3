"""aslip_ros.hw: adapters for real hardware, without ROS.

- :mod:`.xarm`: :class:`~.xarm.XArmAdapter`, the xArm as an ``aslip_ros.arm.Arm`` within the
  limits of :mod:`aslip_ros.control.limits` (:mod:`.xarm_driver`, :mod:`.xarm_config`,
  :mod:`.xarm_sdk`: the SDK calls, settings, and the SDK contained).
- :mod:`.audio_source`: the :class:`~.audio_source.AudioSource` protocol and the sources by
  name (device, wav, bag, sim); :mod:`.audio`: PortAudio capture
  (:class:`~.audio.SoundDeviceCapture`); :mod:`.wav`: WAV replay; :mod:`.sources`: the
  scene's and a bag's audio.
Motion capture needs no adapter here: any driver publishing ``PoseStamped`` feeds
``mocap_bridge`` (docs/hardware.md).

The driver libraries (xarm-python-sdk, sounddevice) are imported lazily, inside the
adapters, so importing this package never needs them.
"""
