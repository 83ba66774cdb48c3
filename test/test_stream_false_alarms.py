"""``python -m benchmarks.stream_false_alarms``: a streaming checkpoint's false alarms on
fresh audio, at each threshold and at its own, per condition; a hybrid read through its
streaming part; other checkpoints refused in one line."""

import json

import numpy as np
import pytest

from aslip_ros.data.export import export
from aslip_ros.data.synthetic import write_synthetic_bag
from aslip_ros.learn.checkpoint import load_checkpoint
from aslip_ros.learn.models.aslip_stream import StreamBackend
from benchmarks import stream_false_alarms as sfa
from test_learn_streaming_model import NAMES, make_checkpoint as make_stream


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """Two trials without slip (the arm moving, the arm still) and one slipping."""
    root = tmp_path_factory.mktemp("fa")
    for i, (v, cond) in enumerate([((0.0, 0.0, 0.0), "robot_moving"),
                                   ((0.0, 0.0, 0.0), "robot_stationary"),
                                   ((0.02, 0.0, 0.0), "robot_moving")]):
        write_synthetic_bag(root / "bags" / f"t{i}", duration_s=2.0, slip_velocity=v, seed=i,
                            channel_names=NAMES, extra_metadata={"condition": cond})
    export([root / "bags"], root / "ds", window_s=0.2, hop_s=0.1, progress=False)
    return root / "ds"


def _pulses(monkeypatch, heights: dict[str, list[float]], ds_root, turns=None):
    """The model's p(slip): zero, with one 0.1 s pulse of each height in ``heights[cond]``
    on the trials of that condition without slip, and 0.92 throughout a slipping trial.
    ``turns``: condition -> [(first frame, frames, |wy| rad/s)] of the rotational output
    on its trials without slip (None: a planar model)."""
    from aslip_ros.learn.data_io import open_dataset
    ds = open_dataset(ds_root)
    slipping = {k for k in range(len(ds.trials))
                if ds.windows["slip"][ds.windows["trial"] == k].any()}
    order = iter(range(len(ds.trials)))       # the benchmark runs every trial, in order

    def offline(self, frames):
        k = next(order)
        p = np.zeros(frames.shape[0], np.float32)
        if k in slipping:
            p[:] = 0.92
        else:
            for j, h in enumerate(heights.get(str(ds.trials[k]["condition"]), [])):
                p[50 + 30 * j:60 + 30 * j] = h
        w = None if turns is None else np.zeros(frames.shape[0], np.float32)
        for first, n, rate in [] if k in slipping or turns is None else \
                turns.get(str(ds.trials[k]["condition"]), []):
            w[first:first + n] = rate
        return p, np.zeros((frames.shape[0], 2), np.float32), w
    monkeypatch.setattr(StreamBackend, "offline", offline)


def test_the_false_alarms_are_counted_per_threshold_and_condition(
        dataset, tmp_path, monkeypatch):
    ck = make_stream(tmp_path / "s.pt", threshold=0.6,
                     threshold_selection={"fa_per_min_target": 2.0, "quiet_minutes": 1.0,
                                          "sweep": [{"threshold": 0.6, "fa_per_min": 1.0}]})
    _pulses(monkeypatch, {"robot_moving": [0.62, 0.72], "robot_stationary": [0.52]}, dataset)
    res = sfa.sweep(ck, dataset)
    rows = {r["threshold"]: r["false_alarms"] for r in res["sweep"]}
    assert rows[0.5] == 3 and rows[0.6] == 2 and rows[0.7] == 1 and rows[0.75] == 0
    # Every rate is counted on the same quiet minutes; the rule takes the first at <= 2.
    assert res["rule_threshold"] == 0.75 and res["threshold"] == 0.6
    assert res["validation_fa_per_min"] == 1.0
    # At its own threshold: 2 false alarms in the 4 s without slip, with a trial interval.
    assert res["fa_per_min"] == pytest.approx(2 / (4.0 / 60.0), rel=0.05)
    lo, hi = res["fa_per_min_ci"]
    assert lo <= res["fa_per_min"] <= hi and lo < hi
    at = res["at_threshold"]
    assert at["robot_moving"]["false_alarms"] == 2
    assert at["robot_stationary"]["false_alarms"] == 0
    # Each trial without slip is 2 s of quiet audio; the slipping one adds none.
    for c in ("robot_moving", "robot_stationary"):
        assert at[c]["quiet_minutes"] == pytest.approx(2.0 / 60.0, abs=0.004)
    # The slipping trial (0.92 throughout) counts no false alarm; its frames are recalled up
    # to its height.
    assert [r["frame_recall"] for r in res["sweep"]] == [1.0] * 9 + [0.0]
    assert "0.60 (the checkpoint's) | 2 |" in sfa.report(res)


def test_a_hybrid_is_read_through_its_streaming_part_and_others_are_refused(tmp_path, capsys):
    from aslip_ros.learn.models.aslip_hybrid import write_hybrid
    from node_support import make_checkpoint
    stream = make_stream(tmp_path / "s.pt", threshold=0.7, angular=True)
    window = make_checkpoint(tmp_path / "w.pt", channel_names=NAMES)
    hybrid = write_hybrid(stream, window, tmp_path / "h.pt")
    part = sfa.stream_part(hybrid)
    assert part.model_type == "aslip_stream" and part.meta["threshold"] == 0.7
    assert part.tensors.keys() == load_checkpoint(stream).tensors.keys()
    assert sfa.main(["--dataset", str(tmp_path), "--checkpoint", str(window)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "aslip_cnn" in err[0] and "streaming" in err[0]


def test_the_figures_are_written(dataset, tmp_path, monkeypatch):
    ck = make_stream(tmp_path / "s.pt", threshold=0.6)
    _pulses(monkeypatch, {}, dataset)
    out = tmp_path / "fa.json"
    assert sfa.main(["--dataset", str(dataset), "--checkpoint", str(ck), "--json",
                     str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["seed"] is None and doc["results"][0]["rule_threshold"] == 0.5
    assert doc["results"][0]["validation_fa_per_min"] is None


def test_the_controllers_stops_count_slip_and_turn_after_its_debounce(
        dataset, tmp_path, monkeypatch):
    """What stops the arm: two consecutive estimates that slip or turn. A one-hop pulse of
    either is no stop; a slip pulse and a turn pulse are one stop each, counted apart."""
    from aslip_ros.control.slip_stop import SlipStopConfig
    cfg = SlipStopConfig()
    assert cfg.debounce_count == 2
    w = cfg.rotation_threshold_rad_s
    ck = make_stream(tmp_path / "s.pt", threshold=0.6)
    _pulses(monkeypatch, {"robot_moving": [0.62]}, dataset,
            turns={"robot_moving": [(120, 5, -1.2 * w), (160, 1, 2 * w)],
                   "robot_stationary": [(100, 1, 3 * w), (140, 4, 0.9 * w)]})
    st = sfa.sweep(ck, dataset)["controller_stops"]
    quiet_min = 4.0 / 60.0              # the two trials without slip or turn label, 2 s each
    assert st["either"]["fa_per_min"] == pytest.approx(2 / quiet_min, rel=0.05)
    assert st["slip"]["fa_per_min"] == pytest.approx(1 / quiet_min, rel=0.05)
    assert st["rotation"]["fa_per_min"] == pytest.approx(1 / quiet_min, rel=0.05)
    # A slip pulse of one hop and a turn of one hop stop nothing.
    np.testing.assert_array_equal(sfa.debounced(np.array([1, 0, 1, 1, 1, 0], bool), 2),
                                  [False, False, False, True, True, False])
    # A planar model has no rotation decision to count.
    _pulses(monkeypatch, {"robot_moving": [0.62]}, dataset)
    res = sfa.sweep(ck, dataset)
    st = res["controller_stops"]
    assert st["rotation"] is None and st["either"] == st["slip"]
    assert "rotation - (no rotational output)" in sfa.report(res)
