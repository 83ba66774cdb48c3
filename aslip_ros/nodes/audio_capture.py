"""``audio_capture``: multi-channel audio -> ``/aslip/audio`` (AudioFrame) + ``/aslip/metadata``.

Sources (``source`` parameter):

- ``device``: a PortAudio input through :class:`aslip_ros.hw.audio.SoundDeviceCapture`
  (device by name or index, channel count, sample rate, channel names), stamped with the
  acquisition time derived from PortAudio's ADC time; input overflows and queue drops are
  counted and reported.
- ``sim``: the simulated scene's audio (``sim.*`` parameters, as for ``scene_sim``).
- ``wav``: a multi-channel WAV file, replayed in real time (:class:`~aslip_ros.hw.audio.
  WavReplay`).
- ``bag``: the AudioFrame messages of a rosbag2 bag, replayed in real time and restamped.

A lifecycle node (it owns hardware): ``configure`` opens the source (a missing device fails
the transition with the list of inputs), ``activate`` starts streaming, ``deactivate``
stops it. With ``autostart`` (default) it does both at start. A reader thread pulls blocks
from the source so the PortAudio callback never waits on ROS.
"""

from __future__ import annotations

import json
import threading
import time
from typing import Optional

import numpy as np
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from std_msgs.msg import String

from aslip_ros.msg import AudioFrame
from aslip_ros.nodes import common as c
from aslip_ros.nodes import convert
from aslip_ros.nodes.scene_sim import build_world, scene_params, world_metadata

SOURCES = ("sim", "device", "wav", "bag")
DEFAULT_NAMES = ["left_front", "left_rear", "right_front", "right_rear"]


class SimAudio:
    """The scene's audio as a paced block source (same ``read`` API as the hw sources)."""

    def __init__(self, world, block_frames: int) -> None:
        self.world = world
        self.block_frames = block_frames
        self.sample_rate = world.fs
        meta = world_metadata(world)
        self.channel_names = list(meta["channel_names"])
        self.metadata = meta
        self._t0: Optional[float] = None
        self._wall0 = 0.0

    def start(self) -> None:
        """Start the real-time clock."""
        self._t0 = time.monotonic()
        self._wall0 = time.time()

    def stop(self) -> None:
        """Nothing to release."""

    def read(self, timeout_s: Optional[float] = None):
        """Next block once it is due in real time (``None`` if not due within the timeout)."""
        from aslip_ros.hw.audio import AudioBlock
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
        """Start the real-time clock."""
        self._t0 = time.monotonic()
        self._wall0 = time.time()
        self._it = self._messages()
        self._offset = None

    def stop(self) -> None:
        """Close the bag."""
        self._reader.close()

    def read(self, timeout_s: Optional[float] = None):
        """Next block, paced by its sample count; ``None`` at the end (unless looping)."""
        from aslip_ros.hw.audio import AudioBlock
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


def _device(value: str):
    """A device given as text: digits are an index, anything else a (sub)name, '' default."""
    value = value.strip()
    if not value:
        return None
    return int(value) if value.isdigit() else value


class AudioCapture(LifecycleNode):
    """Publishes audio blocks from the configured source."""

    def __init__(self) -> None:
        super().__init__("audio_capture")
        specs = [
            c.Param("source", "sim", f"audio source: {', '.join(SOURCES)}", c.one_of(*SOURCES),
                    read_only=True),
            c.Param("block_s", 0.01, "block length [s]", c.in_range(0.001, 0.2),
                    read_only=True),
            c.Param("device", "", "device: PortAudio name (substring) or index; '' = default",
                    read_only=True),
            c.Param("channels", 4, "device: channel count",
                    c.int_range(1, 64), read_only=True),
            c.Param("sample_rate", 48000.0, "device: sample rate [Hz]",
                    c.in_range(1000.0, 384000.0), read_only=True),
            c.Param("channel_names", list(DEFAULT_NAMES),
                    "channel names in column order (device, wav)", read_only=True),
            c.Param("layout", "4mic", "microphone layout name ('' = unknown)", read_only=True),
            c.Param("wav_path", "", "wav: file to replay", read_only=True),
            c.Param("bag_path", "", "bag: rosbag2 to replay", read_only=True),
            c.Param("bag_topic", c.AUDIO_TOPIC, "bag: AudioFrame topic in the bag",
                    c.non_empty, read_only=True),
            c.Param("loop", False, "wav/bag: start over at the end", read_only=True),
            c.Param("metadata_json", "{}",
                    "extra scenario metadata merged into /aslip/metadata (JSON object)",
                    c.Rule(_json_object, "a JSON object"), read_only=True),
            c.Param("frame_id", convert.SENSOR_FRAME, "audio frame id", c.non_empty,
                    read_only=True),
            c.Param("autostart", True, "configure and activate at start", read_only=True),
        ] + scene_params("sim.")
        self.p = c.declare_params(self, specs, cross_check=self._cross_check)
        self.src = None
        self.meta: dict = {}
        self._thread: Optional[threading.Thread] = None
        self._running = threading.Event()
        self.published = 0
        self.frames_lost = 0
        self.overflows = 0
        self.error = ""
        self.finished = False
        self.pub = self.create_publisher(AudioFrame, c.AUDIO_TOPIC, c.SENSOR_QOS)
        self.pub_meta = self.create_publisher(String, c.METADATA_TOPIC, c.LATCHED_QOS)
        self.diag = c.Diagnostics(self, "aslip: audio_capture", self.p["source"])
        self.create_timer(1.0, self._diagnose, callback_group=MutuallyExclusiveCallbackGroup())
        if self.p["autostart"]:
            self.trigger_configure()
            if self.src is not None:
                self.trigger_activate()
        c.ready(self, f"source {self.p['source']}, "
                      f"{'streaming' if self._running.is_set() else 'not streaming'}")

    @staticmethod
    def _cross_check(v: dict) -> Optional[str]:
        names = list(v["channel_names"])
        if v["source"] == "device" and len(names) != v["channels"]:
            return f"channel_names has {len(names)} names for {v['channels']} channels"
        if len(set(names)) != len(names) or any(not str(n) for n in names):
            return f"channel_names must be unique and non-empty: {names}"
        if v["source"] == "wav" and not v["wav_path"]:
            return "source wav needs wav_path"
        if v["source"] == "bag" and not v["bag_path"]:
            return "source bag needs bag_path"
        return None

    # -- lifecycle ------------------------------------------------------------------------------

    def on_configure(self, state) -> TransitionCallbackReturn:
        """Open the source; failure (no device, unreadable file) is reported, not fatal."""
        try:
            self.src, self.meta = self._open()
        except (ValueError, OSError, RuntimeError) as exc:
            self.error = f"{type(exc).__name__}: {exc}"
            self.get_logger().error(f"cannot open audio source: {self.error}")
            self._diagnose()
            return TransitionCallbackReturn.FAILURE
        self.error = ""
        self.pub_meta.publish(String(data=json.dumps(self.meta)))
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state) -> TransitionCallbackReturn:
        """Start the source and the reader thread."""
        try:
            self.src.start()
        except (RuntimeError, OSError) as exc:
            self.error = str(exc)
            self.get_logger().error(f"cannot start audio source: {exc}")
            return TransitionCallbackReturn.FAILURE
        self._running.set()
        self._thread = threading.Thread(target=self._pump, name="audio-pump", daemon=True)
        self._thread.start()
        return super().on_activate(state)

    def on_deactivate(self, state) -> TransitionCallbackReturn:
        """Stop streaming."""
        self._stop_pump()
        return super().on_deactivate(state)

    def on_cleanup(self, state) -> TransitionCallbackReturn:
        """Release the source."""
        self._stop_pump()
        self.src = None
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state) -> TransitionCallbackReturn:
        """Release everything."""
        self.before_shutdown()
        return TransitionCallbackReturn.SUCCESS

    def before_shutdown(self) -> None:
        """Stop the stream before the process exits."""
        self._stop_pump()

    # -- internals ------------------------------------------------------------------------------

    def _open(self):
        p = self.p
        block_s = p["block_s"]
        base = {"format": "aslip-metadata", "version": 1}
        if p["source"] == "sim":
            world = build_world(p, "sim.")
            src = SimAudio(world, max(1, int(round(block_s * world.fs))))
            meta = dict(src.metadata)
            self.layout = meta.get("layout", "")
        elif p["source"] == "device":
            from aslip_ros.hw.audio import SoundDeviceCapture
            rate = float(p["sample_rate"])
            src = SoundDeviceCapture(_device(p["device"]), int(p["channels"]), rate,
                                     block_frames=max(1, int(round(block_s * rate))),
                                     channel_names=list(p["channel_names"]))
            meta = dict(base, sample_rate=rate, channel_names=src.channel_names,
                        layout=p["layout"], device=src.device_name)
            self.layout = p["layout"]
        elif p["source"] == "wav":
            from aslip_ros.hw.wav import WavReplay
            # A first look at the header gives the rate (for the block length) and the
            # channel count (the configured names apply only when they fit the file).
            probe = WavReplay(p["wav_path"], paced=False)
            names = list(p["channel_names"])
            src = WavReplay(p["wav_path"],
                            block_frames=max(1, int(round(block_s * probe.sample_rate))),
                            paced=True, loop=p["loop"],
                            channel_names=names if len(names) == probe.channels else None)
            meta = dict(base, sample_rate=src.sample_rate, channel_names=src.channel_names,
                        layout=p["layout"], source_file=p["wav_path"])
            self.layout = p["layout"]
        else:
            src = BagAudio(p["bag_path"], p["bag_topic"], p["loop"])
            meta = dict(base, **src.metadata)
            meta.update(sample_rate=src.sample_rate, channel_names=src.channel_names)
            self.layout = src.layout or meta.get("layout", "")
        meta.update(json.loads(p["metadata_json"]))
        self.names = list(src.channel_names)
        self.rate = float(src.sample_rate)
        return src, meta

    def _pump(self) -> None:
        src = self.src
        while self._running.is_set():
            try:
                block = src.read(0.2)
            except Exception as exc:  # noqa: BLE001 - report and stop, never crash
                self.error = f"{type(exc).__name__}: {exc}"
                self.get_logger().error(f"audio source failed: {self.error}")
                break
            if block is None:
                if getattr(src, "finished", False) or (self.p["source"] == "bag"):
                    self.finished = True
                    self.get_logger().info("end of replay")
                    break
                continue
            if block.frames_lost_before:
                self.frames_lost += block.frames_lost_before
                self.get_logger().warning(f"{block.frames_lost_before} frames lost before "
                                          f"sample {block.first_sample_index}",
                                          throttle_duration_sec=1.0)
            if block.overflow:
                self.overflows += 1
                self.get_logger().warning("input overflow", throttle_duration_sec=1.0)
            try:
                msg = convert.audio_to_msg(block.first_sample_index,
                                           int(round(block.host_time * 1e9)), self.rate,
                                           self.names, block.data, self.layout,
                                           self.p["frame_id"])
                self.pub.publish(msg)
                self.published += 1
            except Exception as exc:  # noqa: BLE001 - e.g. context shutting down
                self.error = f"{type(exc).__name__}: {exc}"
                self.get_logger().error(f"cannot publish audio: {self.error}",
                                        throttle_duration_sec=1.0)

    def _stop_pump(self) -> None:
        self._running.clear()
        t, self._thread = self._thread, None
        if t is not None:
            t.join(timeout=2.0)
        if self.src is not None:
            try:
                self.src.stop()
            except Exception as exc:  # noqa: BLE001
                self.get_logger().error(f"error stopping the source: {exc}")

    def _diagnose(self) -> None:
        values = {"source": self.p["source"], "blocks_published": self.published,
                  "frames_lost": self.frames_lost, "input_overflows": self.overflows,
                  "streaming": self._running.is_set()}
        stats = getattr(self.src, "stats", None)
        if callable(stats):
            try:
                s = stats()
                values.update(blocks_dropped=s.blocks_dropped, frames_dropped=s.frames_dropped,
                              queue_depth=s.queue_depth)
            except Exception:  # noqa: BLE001 - stats are best effort
                pass
        if self.error:
            level, message = c.Diagnostics.ERROR, self.error
        elif self.frames_lost or self.overflows:
            level, message = c.Diagnostics.WARN, "audio lost (overflow or dropped blocks)"
        elif self.finished:
            level, message = c.Diagnostics.OK, "replay finished"
        elif not self._running.is_set():
            level, message = c.Diagnostics.WARN, "not streaming"
        else:
            level, message = c.Diagnostics.OK, "streaming"
        self.diag.publish(level, message, values)


def _json_object(v) -> Optional[str]:
    try:
        return None if isinstance(json.loads(v), dict) else "must be a JSON object"
    except (TypeError, ValueError) as exc:
        return f"is not JSON ({exc})"


def main(args: Optional[list] = None) -> int:
    """Entry point of ``ros2 run aslip_ros audio_capture``."""
    return c.run_node(AudioCapture, args)


if __name__ == "__main__":
    raise SystemExit(main())
