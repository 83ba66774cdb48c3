"""``benchmarks.device_check``: the CPU/GPU comparison's arithmetic and its refusal."""

import pytest
import torch

from benchmarks import device_check


def _run(device, seed, s_per_epoch, direction):
    return {"device": device, "seed": seed, "s_per_epoch": s_per_epoch,
            "detection_accuracy": 0.99, "direction_mae_deg": direction,
            "magnitude_rmse_mm": 1.5}


def test_speed_up_and_the_seed_spread():
    cpu = [_run("cpu", s, 3.0 + s, d) for s, d in enumerate((4.0, 4.5, 5.0))]
    same = [_run("cuda", s, 0.3, d) for s, d in enumerate((4.2, 4.9, 5.3))]
    out = device_check.summarise(cpu + same)
    assert out["speed_up"] == pytest.approx(4.0 / 0.3)
    assert all(out["within_seed_spread"].values())
    off = [_run("cuda", s, 0.3, d) for s, d in enumerate((9.0, 9.1, 9.2))]
    assert not device_check.summarise(cpu + off)["within_seed_spread"]["direction_mae_deg"]
    assert "speed_up" not in device_check.summarise(cpu)


def test_cuda_without_a_gpu_is_refused_in_one_line(monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert device_check.main(["--out", str(tmp_path), "--devices", "cpu,cuda"]) == 1
    assert "no CUDA GPU" in capsys.readouterr().err
    assert not (tmp_path / "device_check.json").exists()
