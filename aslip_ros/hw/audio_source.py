"""The one interface every audio source satisfies, and the sources by name.

A source delivers :class:`~aslip_ros.hw.audio_block.AudioBlock` objects through a pull API,
so the capture node (``audio_capture``) never knows where the audio comes from: a sound card
(``device``), a WAV file (``wav``), a bag (``bag``), the simulated scene (``sim``) or, in the
ROS layer, another driver's topic (``topic``, :mod:`aslip_ros.nodes.topic_audio`).

A source is opened by a factory from the node's parameter values::

    factory(params: Mapping[str, Any], node) -> OpenedSource

``node`` is the capture node, for sources that subscribe to topics; the sources here ignore
it. :data:`SOURCES` maps the built-in names to their factories; a ``module.path:attribute``
name imports a factory from elsewhere (:func:`resolve_source`, :mod:`aslip_ros.plugin`), so
a new source is one new module and no edit here.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Dict, List, Mapping, Optional, Protocol, runtime_checkable

from aslip_ros import plugin
from aslip_ros.hw.audio import SoundDeviceCapture
from aslip_ros.hw.audio_block import AudioBlock
from aslip_ros.hw.sources import BagAudio, SimAudio, build_world, world_metadata
from aslip_ros.hw.wav import WavReplay

METADATA_BASE = {"format": "aslip-metadata", "version": 1}


@runtime_checkable
class AudioSource(Protocol):
    """A multi-channel block source: ``start``, ``read`` until ``None`` at the end, ``stop``.

    ``sample_rate`` [Hz] and ``channel_names`` (column order) are fixed once opened. A
    source may also have ``finished`` (True once a finite stream ended: ``read`` returning
    ``None`` is then the end, not a late block), ``stats()`` returning
    :class:`~aslip_ros.hw.audio_block.SourceStats` and ``stream_latency`` [s]; the node reports
    them when present.
    """

    sample_rate: float
    channel_names: List[str]

    def start(self) -> None:
        """Start (or resume) delivering blocks."""

    def read(self, timeout_s: Optional[float] = None) -> Optional[AudioBlock]:
        """The next block; ``None`` if none came within ``timeout_s`` or the stream ended."""

    def stop(self) -> None:
        """Stop delivering and release what ``start`` took. Safe to call more than once."""


@dataclass
class OpenedSource:
    """A source opened from parameters, with what the node publishes beside its audio.

    :ivar source: the block source.
    :ivar metadata: scenario metadata for ``/aslip/metadata`` (sample rate and channel names
        at least).
    :ivar layout: microphone layout name for the AudioFrames ('' = unknown).
    :ivar finite: ``read`` returning ``None`` means the end of the stream (a replay).
    """

    source: AudioSource
    metadata: Dict[str, Any] = field(default_factory=dict)
    layout: str = ""
    finite: bool = False


SourceFactory = Callable[[Mapping[str, Any], Any], OpenedSource]


def _frames(block_s: float, rate: float) -> int:
    return max(1, int(round(block_s * rate)))


def _device(value: str):
    """A device given as text: digits are an index, anything else a (sub)name, '' default."""
    value = value.strip()
    if not value:
        return None
    return int(value) if value.isdigit() else value


def open_device(p: Mapping[str, Any], node: Any = None) -> OpenedSource:
    """PortAudio input: ``device``, ``channels``, ``sample_rate``, ``channel_names``,
    ``latency``, ``layout``, ``block_s``."""
    rate = float(p["sample_rate"])
    src = SoundDeviceCapture(_device(p["device"]), int(p["channels"]), rate,
                             block_frames=_frames(p["block_s"], rate),
                             channel_names=list(p["channel_names"]), latency=p["latency"])
    meta = dict(METADATA_BASE, sample_rate=rate, channel_names=src.channel_names,
                layout=p["layout"], device=src.device_name)
    return OpenedSource(src, meta, p["layout"])


def open_wav(p: Mapping[str, Any], node: Any = None) -> OpenedSource:
    """WAV replay in real time: ``wav_path``, ``loop``, ``channel_names``, ``layout``."""
    # A first look at the header gives the rate (for the block length) and the channel
    # count (the configured names apply only when they fit the file).
    probe = WavReplay(p["wav_path"], paced=False)
    names = list(p["channel_names"])
    src = WavReplay(p["wav_path"], block_frames=_frames(p["block_s"], probe.sample_rate),
                    paced=True, loop=p["loop"],
                    channel_names=names if len(names) == probe.channels else None)
    meta = dict(METADATA_BASE, sample_rate=src.sample_rate, channel_names=src.channel_names,
                layout=p["layout"], source_file=p["wav_path"])
    return OpenedSource(src, meta, p["layout"])


def open_bag(p: Mapping[str, Any], node: Any = None) -> OpenedSource:
    """A bag's AudioFrames in real time: ``bag_path``, ``bag_topic``, ``loop``."""
    src = BagAudio(p["bag_path"], p["bag_topic"], p["loop"])
    meta = dict(METADATA_BASE, **src.metadata)
    meta.update(sample_rate=src.sample_rate, channel_names=src.channel_names)
    return OpenedSource(src, meta, src.layout or meta.get("layout", ""), finite=True)


def open_sim(p: Mapping[str, Any], node: Any = None) -> OpenedSource:
    """The simulated scene's audio: the ``sim.*`` scene parameters and ``block_s``."""
    world = build_world(dict(p), "sim.")
    src = SimAudio(world, _frames(p["block_s"], world.fs), world_metadata(world))
    meta = dict(src.metadata)
    return OpenedSource(src, meta, meta.get("layout", ""))


#: The built-in sources by name (the ROS layer adds ``topic``).
SOURCES: Dict[str, SourceFactory] = {
    "sim": open_sim, "device": open_device, "wav": open_wav, "bag": open_bag,
}


def resolve_source(name: str, sources: Mapping[str, SourceFactory] = SOURCES
                   ) -> SourceFactory:
    """The factory of source ``name``: a key of ``sources`` or ``module.path:attribute``.

    Raises ValueError with the choices when the name is neither.
    """
    if name in sources:
        return sources[name]
    return plugin.load(name, f"one of {', '.join(sources)}")
