"""Bad inputs to the scene API raise ValueError with a message that names the problem."""

import dataclasses

import pytest

from aslip_ros.scene import Acoustics, World, scenarios


@pytest.mark.parametrize("kwargs, match", [
    (dict(object="banana"), "unknown object 'banana'"),
    (dict(layout="3mic"), "unknown layout '3mic'"),
    (dict(pad="bumpy"), "unknown pad 'bumpy'"),
    (dict(condition="robot_dancing"), "unknown condition"),
    (dict(duration_s=0.0), "duration_s must be positive"),
    (dict(duration_s=float("nan")), "duration_s must be positive"),
    (dict(sample_rate=-48000.0), "sample_rate must be positive"),
    (dict(sample_rate=4000.0), "at least 8000"),
    (dict(mocap_rate_hz=0.0), "mocap_rate_hz must be positive"),
    (dict(tcp_rate_hz=-1.0), "tcp_rate_hz must be positive"),
    (dict(mocap_latency_s=-0.01), "mocap_latency_s must be >= 0"),
    (dict(mocap_drop_prob=1.0), "mocap_drop_prob"),
    (dict(mocap_noise_m=-1.0), "mocap_noise_m"),
    (dict(max_slip_speed_m_s=0.0), "max_slip_speed_m_s"),
])
def test_external_induced_rejects(kwargs, match):
    with pytest.raises(ValueError, match=match):
        scenarios.external_induced(seed=0, **kwargs)


def test_seed_and_kind_checks():
    with pytest.raises(ValueError, match="seed must be a non-negative integer"):
        scenarios.external_induced(seed=-1)
    with pytest.raises(ValueError, match="seed must be a non-negative integer"):
        scenarios.external_induced(seed=1.5)
    with pytest.raises(ValueError, match="robot_induced slip needs condition"):
        scenarios.robot_induced(seed=0, condition="robot_off")
    with pytest.raises(ValueError, match="unknown scenario kind"):
        scenarios.Scenario("teleport", 0)
    with pytest.raises(ValueError, match="push_dir_xz"):
        scenarios.wall_push(seed=0, push_dir_xz=(0.0, 0.0))
    with pytest.raises(ValueError, match="script segments"):
        scenarios.scripted(seed=0, segments=[(1.0, 0.5, 0.01, 0.0)])
    with pytest.raises(ValueError, match="scripted scenarios keep the arm still"):
        scenarios.scripted(seed=0, segments=[], condition="robot_moving")


def test_acoustics_checks():
    with pytest.raises(ValueError, match="ridge_period_x_m must be positive"):
        scenarios.external_induced(seed=0, acoustics=Acoustics(ridge_period_x_m=0.0))
    with pytest.raises(ValueError, match="slip_level must be finite and >= 0"):
        scenarios.external_induced(seed=0, acoustics=Acoustics(slip_level=-1.0))
    with pytest.raises(ValueError, match="duty"):
        Acoustics(ridge_duty_z=1.0).validate()
    with pytest.raises(ValueError, match="Acoustics instance"):
        scenarios.external_induced(seed=0, acoustics={"slip_level": 1.0})


def test_world_and_stream_checks():
    with pytest.raises(ValueError, match="World needs a Scenario"):
        World({"kind": "external_induced"})
    world = World(scenarios.external_induced(seed=0, duration_s=1.0))
    for bad in (0, -480, 1.5, True):
        with pytest.raises(ValueError, match="block_frames must be a positive integer"):
            next(world.stream(block_frames=bad))
        with pytest.raises(ValueError, match="n_frames must be a positive integer"):
            world.step(bad)
    with pytest.raises(ValueError, match="record=True"):
        world.trajectory()
    open_ended = World(scenarios.wall_push(seed=0))
    with pytest.raises(ValueError, match="use step"):
        next(open_ended.stream())


def test_scenario_is_frozen_and_revalidated():
    scn = scenarios.external_induced(seed=0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        scn.seed = 3
    with pytest.raises(ValueError, match="unknown layout"):
        scn.with_(layout="9mic")
