"""Each output from the candidate that gives it best (#36): the ``per_output`` checkpoint
(learn/models/per_output.py) and ``aslip train``'s per-output choice
(learn/training/selection.py, ``choose_outputs`` and ``compose``)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from aslip_ros.learn.checkpoint import (CheckpointMismatch, load_checkpoint, save_checkpoint,
                                        validate_meta)
from aslip_ros.learn.inference.predictor import Predictor
from aslip_ros.learn.models.per_output import assemble
from aslip_ros.learn.training import selection
from aslip_ros.learn.training.config import TrainResult
from node_support import SCENE_NAMES, make_checkpoint

RATE = 48000.0


@pytest.fixture(scope="module")
def parts(tmp_path_factory):
    """Two CNNs whose answers differ: ``a`` says p 0.9 and (0.02, 0) m/s, ``b`` p 0.2 and
    (0, 0.05) m/s, whatever they hear; ``c`` an untrained one with a rotational head."""
    where = tmp_path_factory.mktemp("per_output")
    return {
        "a": load_checkpoint(make_checkpoint(where / "a.pt", slip_logit=np.log(9.0),
                                             velocity=(0.02, 0.0))),
        "b": load_checkpoint(make_checkpoint(where / "b.pt", slip_logit=np.log(0.25),
                                             velocity=(0.0, 0.05), seed=1)),
        "c": load_checkpoint(make_checkpoint(where / "c.pt", angular=True, seed=2)),
    }


def _windows(n=3, seed=0):
    rng = np.random.default_rng(seed)
    return (0.05 * rng.standard_normal((n, int(0.05 * RATE), len(SCENE_NAMES)))
            ).astype(np.float32)


def test_a_per_output_checkpoint_round_trips_and_gives_each_output_from_its_part(
        parts, tmp_path):
    ck = assemble(parts, {"detection": "a", "speed": "b", "direction": "a"})
    path = save_checkpoint(tmp_path / "po.pt", ck.meta, ck.tensors)
    loaded = load_checkpoint(path)
    assert loaded.model_type == "per_output" and sorted(loaded.meta["parts"]) == ["a", "b"]
    assert loaded.tensors.keys() == ck.tensors.keys()
    out = Predictor(loaded).predict_batch(_windows())
    # p(slip) from a, speed from b (0.05 m/s), direction from a (+x).
    assert out.probability == pytest.approx(np.full(3, 0.9), abs=1e-5)
    assert out.raw_velocity == pytest.approx(np.tile([0.05, 0.0], (3, 1)), abs=1e-5)
    # Direction from b, everything else from a: a's speed along b's +z.
    other = assemble(parts, {"detection": "b", "speed": "a", "direction": "b"})
    out = Predictor(other).predict_batch(_windows())
    assert out.probability == pytest.approx(np.full(3, 0.2), abs=1e-5)
    assert out.raw_velocity == pytest.approx(np.tile([0.0, 0.02], (3, 1)), abs=1e-5)


def test_the_rotation_part_gives_the_rate_and_matches_its_own_predictor(parts, tmp_path):
    ck = assemble(parts, {"detection": "a", "speed": "c", "direction": "c",
                          "rotation": "c"})
    path = save_checkpoint(tmp_path / "rot.pt", ck.meta, ck.tensors)
    x = _windows(4, seed=1)
    got = Predictor.from_checkpoint(path).predict_batch(x)
    own = Predictor(parts["c"]).predict_batch(x)
    assert own.angular is not None
    assert got.angular == pytest.approx(own.angular, abs=1e-6)
    assert got.raw_velocity == pytest.approx(own.raw_velocity, abs=1e-6)
    # Rotation named without a part that estimates it, or wy without a rotation part.
    bad = assemble(parts, {"detection": "a", "speed": "a", "direction": "a",
                           "rotation": "b"})
    assert any("estimates no rotation" in p for p in validate_meta(bad.meta))
    planar = assemble(parts, {"detection": "a", "speed": "b", "direction": "a"})
    planar.meta["outputs"] = ck.meta["outputs"]
    assert any("rotation part" in p for p in validate_meta(planar.meta))


def test_a_mismatched_stream_or_part_is_refused(parts, tmp_path):
    ck = assemble(parts, {"detection": "a", "speed": "b", "direction": "a"})
    with pytest.raises(CheckpointMismatch):
        ck.check_compatible(44100.0, SCENE_NAMES)
    with pytest.raises(CheckpointMismatch):
        ck.check_compatible(RATE, list(reversed(SCENE_NAMES)))
    # A part recorded on other microphones than the checkpoint says: refused on save and
    # on load, naming the part.
    other = load_checkpoint(make_checkpoint(tmp_path / "other.pt",
                                            channel_names=["m0", "m1", "m2", "m3"]))
    bad = assemble(dict(parts, b=other), {"detection": "a", "speed": "b", "direction": "a"})
    with pytest.raises(ValueError, match="parts.b.channel_names"):
        save_checkpoint(tmp_path / "bad.pt", bad.meta, bad.tensors)
    torch.save({"format": "aslip-checkpoint", "version": 1,
                "meta": __import__("json").dumps(bad.meta), "tensors": bad.tensors},
               tmp_path / "bad_on_disk.pt")
    with pytest.raises(ValueError, match="parts.b.channel_names"):
        load_checkpoint(tmp_path / "bad_on_disk.pt")
    # A part that gives nothing, a role naming no part, a part with another calibration.
    unused = assemble(parts, {"detection": "a", "speed": "b", "direction": "a"})
    unused.meta["parts"]["c"] = parts["c"].meta
    assert any("give no output" in p for p in validate_meta(unused.meta))
    missing = assemble(parts, {"detection": "a", "speed": "b", "direction": "a"})
    missing.meta["model_config"]["speed"] = "z"
    assert any("'z', which is not among parts" in p for p in validate_meta(missing.meta))
    calibrated = assemble(parts, {"detection": "a", "speed": "b", "direction": "a"})
    calibrated.meta["parts"]["b"]["calibration"] = {"kind": "made up"}
    assert any("parts.b" in p for p in validate_meta(calibrated.meta))


# --- the choice ---------------------------------------------------------------------------

class _ValSet:
    """What selection reads of a WindowSet: trials, planar labels, window length."""

    window_s = 0.2

    def __init__(self, n_trials=8, per_trial=40, seed=0):
        rng = np.random.default_rng(seed)
        n = n_trials * per_trial
        self.windows = {"trial": np.repeat(np.arange(n_trials), per_trial)}
        a = rng.uniform(-np.pi, np.pi, n)
        s = rng.uniform(0.005, 0.03, n)
        self._v = np.stack([s * np.cos(a), s * np.sin(a)], axis=1)
        self._slip = rng.random(n) < 0.7
        self._v[~self._slip] = 0.0

    def velocity(self, idx):
        return self._v[idx]

    def channel_indices(self, names):
        return list(range(len(names)))

    def window_audio(self, idx, cols):
        return self.audio[np.asarray(idx)]

    def slip(self, idx):
        return self._slip[idx]

    def angular(self, idx):
        return np.full(len(idx), np.nan)

    def has_angular(self, idx=None):
        return False


def _candidate(ds, va, speed_gain, angle_noise_deg, detect_right, seed):
    """Validation predictions of a candidate whose answers are known: the speed times
    ``speed_gain``, the direction off by normal noise of ``angle_noise_deg``, detection right
    on the fraction ``detect_right`` of windows."""
    rng = np.random.default_rng(seed)
    v, slip = ds.velocity(va), ds.slip(va)
    speed = np.linalg.norm(v, axis=1)
    ang = np.arctan2(v[:, 1], v[:, 0]) + np.radians(rng.normal(0, angle_noise_deg, va.size))
    pv = (speed_gain * np.maximum(speed, 0.01))[:, None] * np.stack(
        [np.cos(ang), np.sin(ang)], axis=1)
    right = rng.random(va.size) < detect_right
    prob = np.where(right == slip, 0.9, 0.1)
    return TrainResult(meta={}, tensors={}, history=[],
                       val_pred={"prob": prob, "v": pv, "w": None})


def test_the_choice_takes_each_output_from_the_candidate_better_at_it():
    ds = _ValSet()
    va = np.arange(len(ds.windows["trial"]))
    results = {
        # The winner: sharp direction and detection, its speed 60 % too high.
        "cnn": _candidate(ds, va, 1.6, 5.0, 0.97, seed=1),
        # A regressor of the speed itself, blind to direction, worse at detection.
        "svm": _candidate(ds, va, 1.0, 60.0, 0.85, seed=2),
    }
    # A twin of the winner, its own answer on a tenth of the windows, there a hair better:
    # noise, not evidence, and nothing to gain from the mean of the two.
    own = _candidate(ds, va, 1.6, 4.9, 0.97, seed=3).val_pred
    other = np.random.default_rng(4).random(va.size) < 0.1
    results["twin"] = TrainResult(meta={}, tensors={}, history=[], val_pred={
        k: np.where(other if np.ndim(v) == 1 else other[:, None], own[k], v) if v is not None
        else None for k, v in results["cnn"].val_pred.items()})
    out = selection.choose_outputs(ds, va, results, "cnn")
    assert {r: row["from"] for r, row in out.items()} == {
        "detection": "cnn", "speed": "svm", "direction": "cnn"}
    assert out["speed"]["ci"][1] < 0 and "better than cnn" in out["speed"]["why"]
    assert out["speed"]["value"] < out["speed"]["winner_value"]
    # Order does not decide it, and a winner best at everything gives every output.
    assert selection.choose_outputs(ds, va, dict(reversed(results.items())), "cnn")[
        "speed"]["from"] == "svm"
    alone = selection.choose_outputs(ds, va, {"cnn": results["cnn"]}, "cnn")
    assert {row["from"] for row in alone.values()} == {"cnn"}


def test_two_candidates_that_err_apart_give_the_direction_together():
    """Two candidates whose direction errors are independent (20 deg each): their blend
    errs about 1/sqrt(2) as much and gives the direction; the speed, where one is exact and
    the other 60 % high, stays the exact one's, not the blend's."""
    ds = _ValSet()
    va = np.arange(len(ds.windows["trial"]))
    results = {"cnn": _candidate(ds, va, 1.6, 20.0, 0.97, seed=1),
               "svm": _candidate(ds, va, 1.0, 20.0, 0.97, seed=2)}
    out = selection.choose_outputs(ds, va, results, "cnn")
    assert out["direction"]["from"] in ("cnn+svm", "svm+cnn"), out["direction"]
    from aslip_ros.learn.metrics import compute_metrics
    single = [compute_metrics(r.val_pred["prob"], r.val_pred["v"], ds.velocity(va),
                              ds.slip(va), ds.window_s)["direction_mae_deg"]
              for r in results.values()]
    assert out["direction"]["value"] < 0.85 * min(single)
    assert out["speed"]["from"] == "svm"
    # The blend's predictions are the per_output model's mean of its parts'.
    mixed = selection.blend_prediction({n: r.val_pred for n, r in results.items()},
                                       "cnn+svm")
    units = [r.val_pred["v"] / np.linalg.norm(r.val_pred["v"], axis=1, keepdims=True)
             for r in results.values()]
    want = units[0] + units[1]
    want /= np.linalg.norm(want, axis=1, keepdims=True)
    speed = np.mean([np.linalg.norm(r.val_pred["v"], axis=1) for r in results.values()],
                    axis=0)
    assert mixed["v"] == pytest.approx(want * speed[:, None], abs=1e-6)
    assert mixed["prob"] == pytest.approx(
        (results["cnn"].val_pred["prob"] + results["svm"].val_pred["prob"]) / 2, abs=1e-6)


def test_a_blend_of_parts_gives_their_mean_and_round_trips(parts, tmp_path):
    ck = assemble(parts, {"detection": "a+b", "speed": "a+b", "direction": "a+b"})
    loaded = load_checkpoint(save_checkpoint(tmp_path / "blend.pt", ck.meta, ck.tensors))
    assert sorted(loaded.meta["parts"]) == ["a", "b"]
    out = Predictor(loaded).predict_batch(_windows())
    # p (0.9 + 0.2) / 2; speed (0.02 + 0.05) / 2 along the mean of +x and +z.
    assert out.probability == pytest.approx(np.full(3, 0.55), abs=1e-5)
    assert out.raw_velocity == pytest.approx(
        np.tile([0.035 / np.sqrt(2), 0.035 / np.sqrt(2)], (3, 1)), abs=1e-5)
    # A blend naming a part the checkpoint lacks, or a blend of nothing, is refused.
    bad = assemble(parts, {"detection": "a", "speed": "a+b", "direction": "a"})
    bad.meta["model_config"]["speed"] = "a+z"
    assert any("'z', which is not among parts" in p for p in validate_meta(bad.meta))
    with pytest.raises(ValueError, match="non-empty"):
        selection.blend(["a", ""])


def test_of_two_parts_the_trials_cannot_tell_apart_the_cheaper_one_gives_the_output():
    """The live budget in the choice: two speed regressors as good as each other, one whose
    combination with the winner costs a fifth of the other's (it reads the winner's
    log-mel), give the speed from the cheaper; one clearly worse does not, however cheap."""
    ds = _ValSet()
    va = np.arange(len(ds.windows["trial"]))
    results = {"cnn": _candidate(ds, va, 1.6, 5.0, 0.97, seed=1),
               "svm": _candidate(ds, va, 1.0, 60.0, 0.85, seed=2),
               "svm_logmel": _candidate(ds, va, 1.0, 60.0, 0.85, seed=5)}
    costs = {"cnn": 2.0, "svm": 9.0, "svm_logmel": 2.4}
    asked = []

    def cost(role, name):
        asked.append((role, name))
        return sum(costs[m] for m in name.split("+"))     # a blend runs both
    out = selection.choose_outputs(ds, va, results, "cnn", cost=cost)
    assert out["speed"]["from"] == "svm_logmel", out["speed"]
    assert "cannot be told apart from svm" in out["speed"]["why"]
    assert out["speed"]["cost_ms"] == {"svm": 9.0, "svm_logmel": 2.4}
    assert {r for r, _ in asked} == {"speed"}        # only where an output changes hands
    # Without a cost, or with one that does not save enough, the best gives it.
    assert selection.choose_outputs(ds, va, results, "cnn")["speed"]["from"] in (
        "svm", "svm_logmel")
    costs["svm_logmel"] = 0.9 * costs["svm"]
    best = selection.choose_outputs(ds, va, results, "cnn")["speed"]["from"]
    assert selection.choose_outputs(ds, va, results, "cnn", cost=cost)["speed"]["from"] == best
    # Cheap but clearly worse than the best (its speed 20 % high): not taken.
    results["svm_logmel"] = _candidate(ds, va, 1.2, 60.0, 0.85, seed=5)
    costs["svm_logmel"] = 2.4
    asked.clear()
    assert selection.choose_outputs(ds, va, results, "cnn", cost=cost)["speed"]["from"] == "svm"
    assert asked == [("speed", "svm")]          # a part not good enough is never timed


def test_the_composed_model_scores_each_output_as_its_part_did(parts):
    """``compose`` on real checkpoints: the validation metrics of the combination are the
    chosen parts' own, and the checkpoint it writes predicts what the parts predict."""
    ds = _ValSet(n_trials=4, per_trial=3)
    va = np.arange(len(ds.windows["trial"]))
    x = _windows(va.size, seed=4)
    ds.audio = x
    results = {}
    for name in ("a", "b"):
        p = Predictor(parts[name]).predict_batch(x)
        results[name] = TrainResult(meta=parts[name].meta, tensors=parts[name].tensors,
                                    history=[], val_pred={"prob": p.probability,
                                                          "v": p.raw_velocity, "w": None})
    outputs = {"detection": {"from": "a"}, "speed": {"from": "b"},
               "direction": {"from": "a"}}
    res = selection.compose(ds, va, results, "a", outputs)
    assert res.meta["model_type"] == "per_output" and not validate_meta(res.meta)
    val = res.meta["provenance"]["metrics"]["val"]
    from aslip_ros.learn.metrics import compute_metrics
    own = {n: compute_metrics(r.val_pred["prob"], r.val_pred["v"], ds.velocity(va),
                              ds.slip(va), ds.window_s) for n, r in results.items()}
    assert val["detection_accuracy"] == pytest.approx(own["a"]["detection_accuracy"])
    assert val["magnitude_rmse_mm"] == pytest.approx(own["b"]["magnitude_rmse_mm"], rel=1e-5)
    assert val["direction_mae_deg"] == pytest.approx(own["a"]["direction_mae_deg"], rel=1e-5)
    got = Predictor(res.checkpoint()).predict_batch(x)
    assert got.raw_velocity == pytest.approx(res.val_pred["v"], abs=1e-6)
    assert "output_calibration" in res.meta and res.meta["threshold"] == pytest.approx(
        parts["a"].meta["threshold"], abs=0.5)
    assert set(res.meta["provenance"]["per_output"]["latency_ms"]) == {"per_output", "a"}
    # The winner giving every output: no composition.
    assert selection.compose(ds, va, results, "a", {"speed": {"from": "a"}}) is None
    # What a combination costs, timed on the assembled model (each asked once).
    cost = selection.combination_cost(ds, va, results, "a")
    alone, both = cost("speed", "a"), cost("speed", "b")
    assert 0.0 < alone < np.inf and 0.0 < both < np.inf
    assert cost("speed", "b") == both
