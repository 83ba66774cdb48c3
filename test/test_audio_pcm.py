"""audio_common's raw audio decoded once (aslip_ros.audio_frame: PcmFormat, PcmStream), for
audio_capture and the exporter alike: the GStreamer sample formats, the refusals, the sample
counter the driver does not send."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from aslip_ros.audio_frame import (AudioFrameError, AudioInfoError, PcmFormat, PcmStream,
                                   audio_info_topic)


def info(fmt="S16LE", channels=2, rate=16000, coding="wave"):
    return SimpleNamespace(channels=channels, sample_rate=rate, sample_format=fmt,
                           bitrate=192, coding_format=coding)


def packed24(v, order: str) -> bytes:
    return b"".join(int(x).to_bytes(3, order, signed=True)
                    for x in np.round(v * (2 ** 23 - 1)).ravel())


#: Full scale, as each format writes it: (bytes, expected values at +-1 full scale).
INTS = np.array([[0, -1], [1, 0], [-1, 1]])      # in units of full scale, left/right


@pytest.mark.parametrize("name,encode", [
    ("S16LE", lambda v: np.round(v * 32767).astype("<i2").tobytes()),
    ("S16BE", lambda v: np.round(v * 32767).astype(">i2").tobytes()),
    ("S32LE", lambda v: np.round(v * (2 ** 31 - 1)).astype("<i4").tobytes()),
    ("S24_32LE", lambda v: np.round(v * (2 ** 23 - 1)).astype("<i4").tobytes()),
    ("S24LE", lambda v: packed24(v, "little")),
    ("S24BE", lambda v: packed24(v, "big")),
    ("F32LE", lambda v: v.astype("<f4").tobytes()),
    ("F64BE", lambda v: v.astype(">f8").tobytes()),
    ("U8", lambda v: np.round(v * 127 + 128).astype("u1").tobytes()),
])
def test_every_sample_format_decodes_interleaved_to_full_scale(name, encode):
    fmt = PcmFormat.from_info(info(name.lower()))        # GStreamer's names, any case
    out = fmt.decode(encode(INTS.astype(np.float64)))
    assert out.dtype == np.float32 and out.shape == (3, 2)
    np.testing.assert_allclose(out, INTS, atol=1.0 / 127)   # frame-major: [frame, channel]
    assert fmt.frames(encode(INTS.astype(np.float64))) == 3


def test_integer_extremes_and_the_rclpy_and_rosbags_shapes_of_the_bytes():
    fmt = PcmFormat.from_info(info(channels=1))
    raw = np.array([-32768, 32767, 0, -16384], "<i2").tobytes()
    want = np.array([[-1.0], [32767 / 32768], [0.0], [-0.5]], np.float32)
    for data in (raw, list(raw), np.frombuffer(raw, np.uint8), bytearray(raw)):
        np.testing.assert_array_equal(fmt.decode(data), want)
    # 24-bit samples in 32-bit words: the padding byte is not part of the sample.
    fmt = PcmFormat(1, 48000.0, "S24_32LE")
    assert fmt.decode(np.array([0x7F800000, 0x00800000], "<u4").tobytes())[1, 0] == -1.0


@pytest.mark.parametrize("coding", ["mp3", "MP3", "opus", ""])
def test_compressed_audio_is_refused_with_what_to_set(coding):
    with pytest.raises(AudioInfoError, match="format:=wave") as e:
        PcmFormat.from_info(info(coding=coding))
    assert e.value.reason == "not_pcm"


def test_unusable_infos_and_blocks_are_refused_by_reason():
    for bad, reason in ((info("S20LE"), "sample_format"), (info(channels=0), "no_channels"),
                        (info(rate=0), "bad_rate")):
        with pytest.raises(AudioInfoError) as e:
            PcmFormat.from_info(bad)
        assert e.value.reason == reason
    fmt = PcmFormat.from_info(info("S16LE", channels=2))
    for data, reason in ((b"", "empty"), (b"\0" * 6, "ragged")):
        with pytest.raises(AudioFrameError) as e:
            fmt.decode(data)
        assert e.value.reason == reason
    fmt = PcmFormat.from_info(info("F32LE", channels=1))
    for v, reason in ((np.nan, "non_finite"), (1.5, "out_of_range")):
        with pytest.raises(AudioFrameError) as e:
            fmt.decode(np.array([0.0, v], "<f4").tobytes())
        assert e.value.reason == reason


def test_the_counter_counts_frames_and_leaves_a_lost_blocks_gap():
    s = PcmStream(PcmFormat(1, 16000.0, "S16LE"))
    t0, block_ns = 1_700_000_000_000_000_000, 10_000_000      # 160 frames
    got = [s.place(160, t0 + k * block_ns + jitter)
           for k, jitter in ((0, 0), (1, 2_000_000), (2, -1_000_000), (4, 0), (5, 0))]
    # Jitter under half a block is no gap; the missing block 3 is 160 frames lost.
    assert got == [(0, 0), (160, 0), (320, 0), (640, 160), (800, 0)]
    assert s.frames_lost == 160 and s.next_index == 960
    # Unstamped (zero) or backwards stamps: contiguous, the index never goes back.
    assert s.place(160, 0) == (960, 0) and s.place(160, t0) == (1120, 0)


def test_the_info_topic_is_beside_the_audio():
    assert audio_info_topic("/audio/audio_stamped") == "/audio/audio_info"
    assert audio_info_topic("/mic") == "/audio_info"
    assert audio_info_topic("audio_stamped") == "audio_info"
