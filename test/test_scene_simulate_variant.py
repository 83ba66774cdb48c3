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
