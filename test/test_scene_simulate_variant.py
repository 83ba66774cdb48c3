"""``aslip simulate --variant``: the scene's per-grasp coupling variants reach the bags."""

import pytest

from aslip_ros import cli
from aslip_ros.data import bags

TRIAL = "ext-chips_can-robot_stationary-0000"
ARGS = ["simulate", "--kind", "external", "--trials", "1", "--duration", "1",
        "--objects", "chips_can", "--conditions", "robot_stationary", "--no-progress"]


def _meta(path):
    with bags.BagReader(path) as r:
        return r.read_metadata()


def test_variant_is_recorded_and_not_mixed_with_other_bags(tmp_path):
    assert cli.main(ARGS + ["-o", str(tmp_path / "plain")]) == 0
    assert cli.main(ARGS + ["--variant", "coupling", "-o", str(tmp_path / "cpl")]) == 0
    plain, meta = _meta(tmp_path / "plain" / TRIAL), _meta(tmp_path / "cpl" / TRIAL)
    assert meta["variant"] == "coupling" and "variant" not in plain
    assert meta["seed"] == plain["seed"]                 # the same grasp, another coupling
    # A bag of another variant is refused, not kept in the set.
    assert cli.main(ARGS + ["--variant", "one_sided", "-o", str(tmp_path / "cpl")]) == 1
    with pytest.raises(SystemExit):
        cli.main(ARGS + ["--variant", "loud", "-o", str(tmp_path / "x")])


def test_simulate_knows_every_scene_variant():
    from aslip_ros.scene import simulate
    from aslip_ros.scene import variants
    assert set(simulate.VARIANTS) == set(variants.VARIANTS)


@pytest.mark.parametrize("variant", ["contact", "confounders", "speed", "path"])
def test_new_variants_reach_the_bags(tmp_path, variant):
    assert cli.main(ARGS + ["--variant", variant, "-o", str(tmp_path / variant)]) == 0
    assert _meta(tmp_path / variant / TRIAL)["variant"] == variant


def test_the_audio_interfaces_rate_reaches_the_bags_and_a_bad_one_is_refused(tmp_path,
                                                                             capsys):
    """``--sample-rate``: a lab's interface rate (make scale records 16 kHz to fit hours
    on a disk); export takes the rate from the bag."""
    from aslip_ros.data.export import export
    assert cli.main(ARGS + ["--sample-rate", "16000", "-o", str(tmp_path / "b")]) == 0
    assert _meta(tmp_path / "b" / TRIAL)["sample_rate"] == 16000.0
    assert export([tmp_path / "b"], tmp_path / "ds", progress=False).sample_rate == 16000.0
    assert cli.main(ARGS + ["--sample-rate", "100", "-o", str(tmp_path / "c")]) == 1
    assert "sample_rate must be at least 8000 Hz" in capsys.readouterr().err


def _rms(bag, tmp):
    """The RMS of a bag's audio, as export reads it."""
    import numpy as np
    from aslip_ros.data.dataset import Dataset
    from aslip_ros.data.export import export
    export([bag], tmp, progress=False)
    return float(np.sqrt(np.mean(np.asarray(Dataset(tmp).audio(0), dtype=float) ** 2)))


def test_the_arms_loudness_is_drawn_per_trial_recorded_and_heard(tmp_path, capsys):
    """``--robot-noise-range``: each trial's arm as loud as the scene's times its own factor,
    drawn from the trial's seed; the factor is in the bag, and a set is never mixed with bags
    recorded without it (or with another one)."""
    from aslip_ros.scene.simulate import robot_noise_gain
    # Three seconds: this trial's arm starts to wander after the first.
    moving = ["robot_moving" if a == "robot_stationary" else a for a in ARGS]
    moving[moving.index("--duration") + 1] = "3"
    assert cli.main(moving + ["-o", str(tmp_path / "plain")]) == 0
    assert cli.main(moving + ["--trials", "2", "--robot-noise-range", "0.5,2",
                              "-o", str(tmp_path / "drawn")]) == 0
    drawn = [_meta(tmp_path / "drawn" / f"ext-chips_can-robot_moving-000{i}") for i in (0, 1)]
    gains = [m["robot_noise_gain"] for m in drawn]
    assert all(0.5 <= g <= 2.0 for g in gains) and gains[0] != gains[1]
    assert gains == [round(robot_noise_gain(m["seed"], 0.5, 2.0), 4) for m in drawn]
    assert "robot_noise_gain" not in _meta(tmp_path / "plain" / "ext-chips_can-robot_moving-0000")
    # The same trial with a loud and a quiet arm: only the arm differs, so only it is heard.
    for name, rng in (("loud", "4,4"), ("quiet", "0.25,0.25")):
        assert cli.main(moving + ["--robot-noise-range", rng, "-o", str(tmp_path / name)]) == 0
    trial = "ext-chips_can-robot_moving-0000"
    assert _rms(tmp_path / "loud" / trial, tmp_path / "ds_loud") \
        > 1.2 * _rms(tmp_path / "quiet" / trial, tmp_path / "ds_quiet")
    # Bags drawn otherwise, or not drawn, are refused rather than mixed into the set.
    capsys.readouterr()
    assert cli.main(moving + ["-o", str(tmp_path / "loud")]) == 1
    assert "robot_noise_gain" in capsys.readouterr().err
    assert cli.main(moving + ["--robot-noise-range", "1,1", "-o", str(tmp_path / "loud")]) == 1
    assert cli.main(moving + ["--robot-noise-range", "2,1", "-o", str(tmp_path / "bad")]) == 1
    assert "robot noise range" in capsys.readouterr().err
