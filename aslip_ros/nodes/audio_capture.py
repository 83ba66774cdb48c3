"""``audio_capture``: multi-channel audio -> ``/aslip/audio`` (AudioFrame) + ``/aslip/metadata``.

Sources (``source`` parameter; each an :class:`~aslip_ros.hw.audio_source.AudioSource`
opened by its factory in :data:`aslip_ros.hw.audio_source.SOURCES`, or by
``module.path:factory`` for one outside the package):

- ``device``: a PortAudio input through :class:`aslip_ros.hw.audio.SoundDeviceCapture`
  (device by name or index, channel count, sample rate, channel names), stamped with the
  acquisition time derived from PortAudio's ADC time; input overflows and queue drops are
  counted and reported.
- ``sim``: the simulated scene's audio (``sim.*`` parameters, as for ``scene_sim``).
- ``wav``: a multi-channel WAV file, replayed in real time
  (:class:`~aslip_ros.hw.wav.WavReplay`).
- ``bag``: the AudioFrame messages of a rosbag2 bag, replayed in real time and restamped.
- ``topic``: another driver's AudioFrames on ``input_topic`` (:mod:`.topic_audio`), checked
  against ``sample_rate`` and ``channel_names``; with ``input_type:=audio_common``,
  audio_common's ``AudioDataStamped`` in the format of its latched ``AudioInfo`` (on
  ``info_topic``): its rate and channel count, published once it has come (the metadata
  too), while the diagnostics name what the source waits for or why it refuses the audio.

A lifecycle node (it owns hardware): ``configure`` opens the source (a missing device fails
the transition with the list of inputs), ``activate`` starts streaming, ``deactivate``
stops it. With ``autostart`` (default) it does both at start. A reader thread pulls blocks
from the source so the PortAudio callback never waits on ROS. With ``exit_on_error`` (a
launch that records the audio) a source that cannot be opened or started at autostart, or
fails while streaming, ends the process with exit code 1 instead of leaving it up silent.

Faults a real sound card meets are visible downstream, never spliced over:

- A source that stops delivering for ``stall_timeout_s`` turns the diagnostics to ERROR at
  once (not at the next period); failed audio callbacks are an ERROR too.
- A reopened source (``activate`` again, or a new ``configure``) is a new stream, but the
  published sample index never goes back: it continues after the last published block,
  advanced by the time that passed, so index and stamp stay consistent and a consumer
  sees one gap rather than a stream that went back in time.
- ``latency`` is PortAudio's suggested input latency (default ``low``); the diagnostics
  report the stream's actual input latency and the capture latency (acquisition of a
  block's last sample to its publication).
"""

from __future__ import annotations

import collections
import json
import threading
import time
from typing import Optional

import numpy as np
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from std_msgs.msg import String

from aslip_ros.hw import audio_source
from aslip_ros.hw.audio import check_latency
from aslip_ros.msg import AudioFrame
from aslip_ros.nodes import common as c
from aslip_ros.runtime.process import ready, run_node
from aslip_ros.runtime.qos import LATCHED_QOS, SENSOR_QOS
from aslip_ros.nodes import convert
from aslip_ros.nodes.scene_params import scene_params
from aslip_ros.nodes.topic_audio import INPUT_TYPES, open_topic
from aslip_ros.scene.layouts import DEFAULT_LAYOUT, LAYOUTS

#: Sources by name: the ROS-free ones of hw/ and the topic bridge.
SOURCES = dict(audio_source.SOURCES, topic=open_topic)
_SOURCE_CHOICES = f"one of {', '.join(SOURCES)}, or module.path:factory"
#: The default microphones: the scene's 4-microphone layout, the names the shipped models
#: and docs/hardware.md use (a cell with other microphones names its own).
DEFAULT_NAMES = list(LAYOUTS[DEFAULT_LAYOUT].channel_names)
#: Seconds between two tries to start the stream.
START_RETRY_S = 1.0


def _source(v) -> Optional[str]:
    try:
        audio_source.resolve_source(str(v), SOURCES)
    except ValueError as exc:
        return str(exc)
    return None


class AudioCapture(LifecycleNode):
    """Publishes audio blocks from the configured source."""

    def __init__(self, **kwargs) -> None:
        """``kwargs`` go to ``rclpy`` (e.g. ``parameter_overrides``, ``context``)."""
        super().__init__("audio_capture", **kwargs)
        specs = [
            c.Param("source", "sim", "audio source", c.Rule(_source, _SOURCE_CHOICES),
                    read_only=True),
            c.Param("block_s", 0.01, "block length [s]", c.in_range(0.001, 0.2),
                    read_only=True),
            c.Param("device", "", "device: PortAudio name (substring) or index; '' = default",
                    read_only=True),
            c.Param("input_topic", "", "topic: topic to bridge (AudioFrame, or audio_common's "
                    "AudioDataStamped)", read_only=True),
            c.Param("input_type", "aslip", "topic: aslip (AudioFrame) or audio_common "
                    "(AudioDataStamped + AudioInfo; needs the driver's format:=wave)",
                    c.one_of(*INPUT_TYPES), read_only=True),
            c.Param("info_topic", "", "topic, audio_common: AudioInfo topic ('' = audio_info "
                    "beside input_topic)", read_only=True),
            c.Param("channels", 4, "device: channel count",
                    c.int_range(1, 64), read_only=True),
            c.Param("sample_rate", 48000.0, "device, topic: sample rate [Hz]",
                    c.in_range(1000.0, 384000.0), read_only=True),
            c.Param("channel_names", list(DEFAULT_NAMES),
                    "channel names in column order (device, wav, topic)", read_only=True),
            c.Param("layout", DEFAULT_LAYOUT, "microphone layout name ('' = unknown)",
                    read_only=True),
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
            c.Param("exit_on_error", False, "exit with code 1 when the source cannot be "
                    "opened or started at autostart, or fails while streaming",
                    read_only=True),
            c.Param("latency", "low", "device: PortAudio input latency: low, high or seconds",
                    _latency, read_only=True),
            c.Param("start_attempts", 3, "tries to start the stream before activation fails",
                    c.int_range(1, 10), read_only=True),
            c.Param("stall_timeout_s", 0.5,
                    "no block for this long is an ERROR (device stopped delivering) [s]",
                    c.in_range(0.05, 10.0)),
        ] + scene_params("sim.")
        self.p = c.declare_params(self, specs, cross_check=self._cross_check)
        self.src = None
        self.finite = False                    # the source's end is the end of the stream
        self.meta: dict = {}
        self._thread: Optional[threading.Thread] = None
        self._running = threading.Event()
        self.published = 0
        self.frames_lost = 0
        self.overflows = 0
        self.error = ""
        self.finished = False
        self.done = False                      # run_node exits with exit_code once set
        self.exit_code = 0
        self.stalled = 0.0                     # seconds without a block, once stalled
        self.restarts = 0
        self._next_index: Optional[int] = None     # after the last published block
        self._next_time = 0.0                      # its host time [s]
        self._base = 0                             # published index - source index
        self.capture_latency = collections.deque(maxlen=1000)
        self.pub = self.create_publisher(AudioFrame, c.AUDIO_TOPIC, SENSOR_QOS)
        self.pub_meta = self.create_publisher(String, c.METADATA_TOPIC, LATCHED_QOS)
        self.diag = c.Diagnostics(self, "aslip: audio_capture", self.p["source"])
        self.create_timer(1.0, self._diagnose, callback_group=MutuallyExclusiveCallbackGroup())
        if self.p["autostart"]:
            self.trigger_configure()
            if self.src is not None:
                self.trigger_activate()
            if not self._running.is_set():
                self._exit_on_error()
        if not self.done:       # exit_on_error: on its way out, not ready
            ready(self, f"source {self.p['source']}, "
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
        if v["source"] == "topic" and not v["input_topic"]:
            return "source topic needs input_topic"
        if v["input_type"] == "audio_common" and v["source"] != "topic":
            return "input_type audio_common is for source topic"
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
        if self.rate:           # else it goes out with the stream's format (_learn_format)
            self.pub_meta.publish(String(data=json.dumps(self.meta)))
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state) -> TransitionCallbackReturn:
        """Start the source (``start_attempts`` tries, ``START_RETRY_S`` apart: an interface
        that is slow to deliver its first period times PortAudio's start out) and the
        reader thread."""
        attempts = self.p["start_attempts"]
        for attempt in range(1, attempts + 1):
            try:
                self.src.start()
                break
            except (RuntimeError, OSError) as exc:
                self.error = str(exc)
                if attempt == attempts:
                    self.get_logger().error(f"cannot start audio source ({attempts} "
                                            f"attempts): {exc}")
                    return TransitionCallbackReturn.FAILURE
                self.get_logger().warning(f"audio source did not start (attempt {attempt} of "
                                          f"{attempts}): {exc}; retrying in "
                                          f"{START_RETRY_S:g} s")
                time.sleep(START_RETRY_S)
        self.error = ""
        self.stalled = 0.0
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
        opened = audio_source.resolve_source(self.p["source"], SOURCES)(self.p, self)
        src = opened.source
        meta = dict(opened.metadata)
        meta.update(json.loads(self.p["metadata_json"]))
        self.layout = opened.layout
        self.finite = opened.finite
        self.names = list(src.channel_names)
        self.rate = float(src.sample_rate)     # 0 until a stream's AudioInfo says it
        return src, meta

    def _pump(self) -> None:
        src = self.src
        fresh = True                       # the first block of this activation
        last_block = time.monotonic()
        while self._running.is_set():
            try:
                block = src.read(0.1)
            except Exception as exc:  # noqa: BLE001 - report and stop, never crash
                self.error = f"{type(exc).__name__}: {exc}"
                self.get_logger().error(f"audio source failed: {self.error}")
                self._diagnose()
                self._exit_on_error()
                break
            if block is None:
                if getattr(src, "finished", False) or self.finite:
                    self.finished = True
                    self.get_logger().info("end of replay")
                    break
                if _held_back(src):         # silent on purpose: no stall, now or later
                    last_block = time.monotonic()
                self._check_stall(time.monotonic() - last_block)
                continue
            last_block = time.monotonic()
            if self.stalled:
                self.get_logger().info(f"audio is back after {self.stalled:.2f} s")
                self.stalled = 0.0
                self._diagnose()
            if fresh:
                self._learn_format(src)
                self._rebase(block)
                fresh = False
            self._publish(block)

    def _learn_format(self, src) -> None:
        """A source that learns its format from the stream (audio_common's AudioInfo)
        knows it by its first block: the metadata goes out with it then."""
        rate, names = float(src.sample_rate), list(src.channel_names)
        if (rate, names) == (self.rate, self.names):
            return
        self.rate, self.names = rate, names
        self.meta.update(sample_rate=rate, channel_names=names)
        self.pub_meta.publish(String(data=json.dumps(self.meta)))

    def _exit_on_error(self) -> None:
        if self.p["exit_on_error"]:
            self.get_logger().error(f"no audio on {c.AUDIO_TOPIC} from source "
                                    f"{self.p['source']}: exiting with code 1 (exit_on_error)")
            self.exit_code, self.done = 1, True

    def _check_stall(self, silent_s: float) -> None:
        if silent_s < self.p["stall_timeout_s"]:
            return
        first = not self.stalled
        self.stalled = silent_s
        if first:
            self.get_logger().error(f"no audio from the source for {silent_s:.2f} s")
            self._diagnose()

    def _rebase(self, block) -> None:
        """A new stream: publish its indices after the last one, advanced by the pause."""
        if self._next_index is None:
            self._base = 0
            return
        pause = max(0.0, block.host_time - self._next_time)
        first = self._next_index + max(1, int(round(pause * self.rate)))
        self._base = first - block.first_sample_index
        self.restarts += 1
        self.get_logger().warning(f"audio stream restarted: sample index continues at "
                                  f"{first} after {pause:.3f} s")

    def _publish(self, block) -> None:
        if block.frames_lost_before:
            self.frames_lost += block.frames_lost_before
            self.get_logger().warning(f"{block.frames_lost_before} frames lost before "
                                      f"sample {block.first_sample_index}",
                                      throttle_duration_sec=1.0)
        if block.overflow:
            self.overflows += 1
            self.get_logger().warning("input overflow", throttle_duration_sec=1.0)
        index = block.first_sample_index + self._base
        try:
            msg = convert.audio_to_msg(index, int(round(block.host_time * 1e9)), self.rate,
                                       self.names, block.data, self.layout,
                                       self.p["frame_id"])
            self.pub.publish(msg)
            self.published += 1
        except Exception as exc:  # noqa: BLE001 - e.g. context shutting down
            self.error = f"{type(exc).__name__}: {exc}"
            self.get_logger().error(f"cannot publish audio: {self.error}",
                                    throttle_duration_sec=1.0)
            return
        end_time = block.host_time + block.frames / self.rate
        self.capture_latency.append(time.time() - end_time)
        self._next_index, self._next_time = index + block.frames, end_time

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
                  "streaming": self._running.is_set(), "stream_restarts": self.restarts,
                  "seconds_without_audio": round(self.stalled, 3)}
        errors = 0
        stats = getattr(self.src, "stats", None)
        if callable(stats):
            try:
                s = stats()
                errors = s.callback_errors
                values.update(blocks_dropped=s.blocks_dropped, frames_dropped=s.frames_dropped,
                              queue_depth=s.queue_depth, callback_errors=errors)
            except Exception:  # noqa: BLE001 - stats are best effort
                pass
        lat = np.array(self.capture_latency) * 1e3
        if lat.size:
            values.update(capture_latency_p50_ms=float(np.percentile(lat, 50)),
                          capture_latency_max_ms=float(lat.max()))
        stream_latency = getattr(self.src, "stream_latency", None)
        if isinstance(stream_latency, float):
            values["stream_latency_ms"] = stream_latency * 1e3
        if self.error:
            level, message = c.Diagnostics.ERROR, self.error
        elif getattr(self.src, "refusal", ""):
            level, message = c.Diagnostics.ERROR, self.src.refusal
        elif getattr(self.src, "waiting_for", ""):
            level, message = c.Diagnostics.WARN, f"waiting for {self.src.waiting_for}"
        elif self.stalled and self._running.is_set():
            level, message = c.Diagnostics.ERROR, (f"no audio for {self.stalled:.2f} s: the "
                                                   "source stopped delivering")
        elif errors:
            level, message = c.Diagnostics.ERROR, f"{errors} audio callback errors (audio lost)"
        elif self.frames_lost or self.overflows:
            level, message = c.Diagnostics.WARN, "audio lost (overflow or dropped blocks)"
        elif self.finished:
            level, message = c.Diagnostics.OK, "replay finished"
        elif not self._running.is_set():
            level, message = c.Diagnostics.WARN, "not streaming"
        else:
            level, message = c.Diagnostics.OK, "streaming"
        self.diag.publish(level, message, values)


def _held_back(src) -> bool:
    """Whether ``src`` publishes nothing on purpose (it waits for its format, or refuses
    the stream): its diagnostics say why, and silence is no stall."""
    return bool(getattr(src, "refusal", "") or getattr(src, "waiting_for", ""))


def _latency(v) -> Optional[str]:
    try:
        check_latency(v)
    except ValueError as exc:
        return str(exc)
    return None


def _json_object(v) -> Optional[str]:
    try:
        return None if isinstance(json.loads(v), dict) else "must be a JSON object"
    except (TypeError, ValueError) as exc:
        return f"is not JSON ({exc})"


def main(args: Optional[list] = None) -> int:
    """Entry point of ``ros2 run aslip_ros audio_capture``."""
    return run_node(AudioCapture, args)


if __name__ == "__main__":
    raise SystemExit(main())
