"""A bag of audio_common's own topics (``audio_stamped`` + latched ``audio_info``, as ``ros2
bag record`` takes them from audio_capture_node) exports to the same dataset as the bag of
the AudioFrames that audio_capture makes of the same messages."""

from __future__ import annotations

import numpy as np
import pytest

from aslip_ros.audio_frame import AUDIO_COMMON_INFO_TYPE, AUDIO_COMMON_STAMPED_TYPE
from aslip_ros.data import bag_format
from aslip_ros.data.bags import AUDIO_TYPE, BagError, BagReader, BagWriter
from aslip_ros.data.dataset import Dataset
from aslip_ros.data.export import export
from aslip_ros.data.synthetic import write_synthetic_bag
from node_support import driver_msgs

RATE, BLOCK = 16000.0, 160
LOST = 37                     # the block lost between the driver and the recorder


def _store():
    driver_msgs("audio_common_msgs")          # the installed definitions, or skip
    store = bag_format.project_store()
    for t in (AUDIO_COMMON_STAMPED_TYPE, AUDIO_COMMON_INFO_TYPE):
        assert bag_format.add_installed_types(store, t)
    return store


def _two_bags(tmp_path, coding="wave", late_info=True, info=True):
    """The same recording twice: (a) AudioFrames, (b) audio_common's pair as the driver
    sends it (S16LE bytes, empty frame_id, its capture stamps, the info latched and re-sent;
    with ``late_info`` logged after the first audio). Poses and metadata as recorded."""
    src = tmp_path / "src"
    write_synthetic_bag(src, duration_s=2.0, sample_rate=RATE, channel_names=["mic"],
                        block_frames=BLOCK, slip_velocity=(0.02, 0.0, -0.01), layout="")
    store = _store()
    T = store.types
    with BagReader(src) as r:
        meta = r.metadata
        msgs = list(r.messages())
    out = {}
    for kind in ("frames", "audio_common"):
        path = out[kind] = tmp_path / kind / "trial"
        with BagWriter(path, metadata=meta, store=store) as bag:
            infos = 0
            for m in msgs:
                if m.topic == "/aslip/metadata":
                    continue
                if m.msgtype != AUDIO_TYPE:
                    bag.write(m.topic, m.msgtype, m.msg, m.log_ns, qos="sensor")
                    continue
                k = m.msg.first_sample_index // BLOCK
                pcm = np.round(np.clip(m.msg.data, -1, 1) * 32767).astype("<i2")
                if k == LOST:
                    continue
                if kind == "frames":
                    m.msg.data = (pcm / 32768.0).astype(np.float32)
                    bag.write(m.topic, AUDIO_TYPE, m.msg, m.log_ns, qos="sensor")
                    continue
                if info and (infos == 0 and (k >= 3 or not late_info) or
                             infos == 1 and k == 100):
                    msg = T[AUDIO_COMMON_INFO_TYPE](channels=1, sample_rate=int(RATE),
                                                    sample_format="S16LE", bitrate=192,
                                                    coding_format=coding)
                    bag.write("/audio/audio_info", AUDIO_COMMON_INFO_TYPE, msg, m.log_ns,
                              qos="latched")
                    infos += 1
                header = T["std_msgs/msg/Header"](stamp=m.msg.header.stamp, frame_id="")
                audio = T["audio_common_msgs/msg/AudioData"](
                    data=np.frombuffer(pcm.tobytes(), np.uint8))
                bag.write("/audio/audio_stamped", AUDIO_COMMON_STAMPED_TYPE,
                          T[AUDIO_COMMON_STAMPED_TYPE](header=header, audio=audio), m.log_ns)
    return out


def test_audio_common_bag_is_the_audio_frame_bags_dataset(tmp_path):
    bags = _two_bags(tmp_path)
    got = {}
    for kind, path in bags.items():
        s = export([path], tmp_path / f"ds_{kind}", window_s=0.1, hop_s=0.05, progress=False)
        got[kind] = (s, Dataset(tmp_path / f"ds_{kind}"))
    (s_a, a), (s_b, b) = got["frames"], got["audio_common"]
    assert b.sample_rate == RATE and b.channel_names == a.channel_names == ["mic"]
    assert s_b.kept == s_a.kept > 0 and s_b.dropped == s_a.dropped
    assert s_a.dropped["audio_gap"] > 0                 # the lost block, in both
    np.testing.assert_array_equal(np.asarray(b.windows), np.asarray(a.windows))
    np.testing.assert_array_equal(np.load(tmp_path / "ds_audio_common" / "audio" / "0.npy"),
                                  np.load(tmp_path / "ds_frames" / "audio" / "0.npy"))
    ta, tb = a.trials[0], b.trials[0]
    assert ta["first_sample_index"] == tb["first_sample_index"] == 0
    assert tb["start_stamp_ns"] == ta["start_stamp_ns"] and tb["audio_gaps"] == 1


def test_mp3_or_a_missing_audio_info_refuses_the_bag_saying_what_to_do(tmp_path):
    bags = _two_bags(tmp_path / "mp3", coding="mp3")
    with pytest.raises(BagError, match="coding_format 'mp3'.*format:=wave"):
        export([bags["audio_common"]], tmp_path / "ds", progress=False)
    assert not (tmp_path / "ds").exists()
    bags = _two_bags(tmp_path / "no_info", info=False)
    with pytest.raises(BagError, match="no audio_common_msgs/msg/AudioInfo on "
                                       "/audio/audio_info.*record audio_info too"):
        export([bags["audio_common"]], tmp_path / "ds", progress=False)
