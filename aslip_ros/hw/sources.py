"""Paced block sources beside the live capture: the simulated scene's audio and a bag's
AudioFrames, with the pull API of :mod:`aslip_ros.hw.audio` (``start``/``read``/``stop``).

Also the scene built from parameter values (:func:`build_world`), shared by the
``scene_sim`` node and the ``sim`` audio source.

A restarted source resumes its clock where its sample index stands, so its first block after
``start`` is due at once (not after as long as the earlier stream ran).
"""

from __future__ import annotations

import time
from typing import Optional

import numpy as np

from aslip_ros.hw.audio_block import AudioBlock

#: Task names accepted by the ``scenario`` parameter -> scene scenario builders.
SCENARIOS = ("external_induced", "robot_induced", "wall_push", "drag", "pivot")
#: The pivot's push in the grasp plane (x, z): down, onto a surface that meets the object off
#: the grasp axis (``pivot_lever_m``), so that it turns (docs/scene.md).
PIVOT_PUSH_DIR_XZ = (0.0, -1.0)
CONDITIONS = ("robot_off", "robot_stationary", "robot_moving")


def build_world(values: dict, prefix: str = ""):
    """A :class:`aslip_ros.scene.World` from scene parameter values (open-ended duration).

    ``values`` holds ``<prefix>scenario``, ``seed``, ``object``, ``layout``, ``pad``,
    ``condition``, ``sample_rate``, ``wall_distance_m``, ``drag_speed_m_s``, ``pivot_lever_m``
    (``pivot``: a wall push down, met that far along the fingers, so the object turns) and
    (optional) ``drag_hold_s``, ``variant`` and ``robot_noise_x`` (:func:`stressed`); an
    unusable combination raises ValueError.
    """
    from aslip_ros.scene import World, scenarios
    g = {k[len(prefix):]: v for k, v in values.items() if k.startswith(prefix)}
    common = dict(seed=int(g["seed"]), object=g["object"], layout=g["layout"], pad=g["pad"],
                  sample_rate=float(g["sample_rate"]))
    kind = g["scenario"]
    try:
        if kind == "external_induced":
            scn = scenarios.external_induced(condition=g["condition"], duration_s=None,
                                             **common)
        elif kind == "robot_induced":
            scn = scenarios.robot_induced(duration_s=None, **common)
        elif kind == "wall_push":
            scn = scenarios.wall_push(wall_distance_m=float(g["wall_distance_m"]), **common)
        elif kind == "pivot":
            scn = scenarios.wall_push(wall_distance_m=float(g["wall_distance_m"]),
                                      push_dir_xz=PIVOT_PUSH_DIR_XZ,
                                      pivot_lever_m=float(g["pivot_lever_m"]), **common)
        else:
            hold = {"drag_hold_s": float(g["drag_hold_s"])} if "drag_hold_s" in g else {}
            scn = scenarios.external_drag(drag_speed_m_s=float(g["drag_speed_m_s"]), **hold,
                                          **common)
    except ValueError as exc:
        raise ValueError(f"cannot build the {kind} scenario: {exc}") from exc
    return World(stressed(scn, g.get("variant", NO_VARIANT), g.get("robot_noise_x", 1.0)))


#: The ``variant`` parameter's value for the default scene.
NO_VARIANT = "none"


def stressed(scn, variant: str | None = NO_VARIANT, robot_noise_x: float = 1.0):
    """``scn`` under a held-out scene variant (a name in
    :data:`aslip_ros.scene.variants.VARIANTS`; ``none`` or None: the default scene), its
    robot noise level then ``robot_noise_x`` times as loud (``Acoustics.robot_level``).
    ``none`` and 1 return ``scn`` itself."""
    from dataclasses import replace

    from aslip_ros.scene.variants import VARIANTS
    if variant not in (None, NO_VARIANT):
        if variant not in VARIANTS:
            raise ValueError(f"unknown scene variant {variant!r}; choose one of "
                             f"{[NO_VARIANT, *VARIANTS]}")
        scn = VARIANTS[variant](scn)
    x = float(robot_noise_x)
    if not (np.isfinite(x) and x >= 0.0):
        raise ValueError(f"robot_noise_x must be finite and >= 0, got {robot_noise_x!r}")
    if x != 1.0:
        scn = scn.with_(acoustics=replace(scn.acoustics,
                                          robot_level=scn.acoustics.robot_level * x))
    return scn


def world_metadata(world) -> dict:
    """The scene's metadata plus the task geometry a controller may need (``task``)."""
    meta = world.metadata()
    task = {"kind": world.scenario.kind}
    if world.scenario.kind == "wall_push":
        task.update(push_direction=world.wall_normal().tolist(),
                    wall_point=world.wall_position().tolist(),
                    object_length_m=float(world.object.length_m))
    meta["task"] = task
    return meta


class SimAudio:
    """The scene's audio as a paced block source (same ``read`` API as the hw sources)."""

    def __init__(self, world, block_frames: int, metadata: dict) -> None:
        self.world = world
        self.block_frames = block_frames
        self.sample_rate = world.fs
        self.channel_names = list(metadata["channel_names"])
        self.metadata = metadata
        self._t0: Optional[float] = None
        self._wall0 = 0.0

    def start(self) -> None:
        """Start (or resume) the real-time clock: the next block is due now."""
        elapsed = self.world.sample_index / self.sample_rate
        self._t0 = time.monotonic() - elapsed
        self._wall0 = time.time() - elapsed

    def stop(self) -> None:
        """Nothing to release."""

    def read(self, timeout_s: Optional[float] = None):
        """Next block once it is due in real time (``None`` if not due within the timeout)."""
        if self._t0 is None:
            self.start()
        i = self.world.sample_index
        due = self._t0 + (i + self.block_frames) / self.sample_rate
        wait = due - time.monotonic()
        if wait > 0:
            if timeout_s is not None and wait > timeout_s:
                time.sleep(timeout_s)
                return None
            time.sleep(wait)
        chunk = self.world.step(self.block_frames)
        return AudioBlock(chunk.first_sample_index, chunk.t0, self._wall0 + chunk.t0,
                          chunk.audio)


class BagAudio:
    """AudioFrame messages of a bag as a paced block source; stamps restart at replay time.

    Sample indices restart at 0 but keep the bag's gaps (blocks missing from the recording
    are reported as frames lost before the next block, and their time is waited out), so a
    consumer never splices audio across a gap. Each loop pass continues the index.
    """

    def __init__(self, path: str, topic: str, loop: bool) -> None:
        from aslip_ros.data.bags import BagReader
        self._path, self._topic, self._loop = path, topic, loop
        self._reader = BagReader(path)
        self._reader.open()
        self._reader.require([topic], "audio replay")
        self.metadata = self._reader.metadata or {}
        first = next(iter(self._messages()), None)
        if first is None:
            raise ValueError(f"bag {path} has no messages on {topic}")
        self.sample_rate = float(first.sample_rate)
        self.channel_names = [str(n) for n in first.channel_names]
        self.layout = str(first.layout)
        self._it = None
        self._t0: Optional[float] = None
        self._index = 0
        self._offset: Optional[int] = None   # bag sample index - replay index, this pass
        self._wall0 = 0.0

    def _messages(self):
        for m in self._reader.messages([self._topic]):
            yield m.msg

    def start(self) -> None:
        """Start (or restart from the bag's beginning) the real-time clock: due now."""
        elapsed = self._index / self.sample_rate
        self._t0 = time.monotonic() - elapsed
        self._wall0 = time.time() - elapsed
        self._it = self._messages()
        self._offset = None

    def stop(self) -> None:
        """Close the bag."""
        self._reader.close()

    def read(self, timeout_s: Optional[float] = None):
        """Next block, paced by its sample count; ``None`` at the end (unless looping)."""
        if self._t0 is None:
            self.start()
        msg = next(self._it, None)
        if msg is None:
            if not self._loop:
                return None
            self._it = self._messages()
            self._offset = None
            msg = next(self._it, None)
            if msg is None:
                return None
        n_ch = len(self.channel_names)
        data = np.asarray(msg.data, dtype=np.float32)
        if n_ch == 0 or data.size % n_ch or list(msg.channel_names) != self.channel_names:
            return None
        block = data.reshape(-1, n_ch)
        bag_index = int(msg.first_sample_index)
        if self._offset is None:
            self._offset = bag_index - self._index
        index = bag_index - self._offset
        if index < self._index:
            # A repeated or backwards index in the bag: continue contiguously from here.
            self._offset, index = bag_index - self._index, self._index
        lost = index - self._index
        wait = self._t0 + (index + block.shape[0]) / self.sample_rate - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        t = index / self.sample_rate
        out = AudioBlock(index, t, self._wall0 + t, block, frames_lost_before=lost)
        self._index = index + block.shape[0]
        return out
