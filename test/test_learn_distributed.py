"""``aslip train`` under ``torchrun --nproc_per_node 2`` (#38), gloo on the CPU: the same
recipe chosen as in one process, and validation figures within the seed spread.

Each case runs the real ``torch.distributed.run`` launcher; rank 0 alone writes. The
one-process runs they are compared with run in this process, and a refusal under torchrun in
a process group of one rank joined here.
"""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from aslip_ros.learn.checkpoint import load_checkpoint
from aslip_ros.learn.synthetic import make_synthetic_dataset

pytestmark = pytest.mark.slow

ARGS = ["--width", "8", "--depth", "2", "--temporal-channels", "32", "--head-hidden", "16",
        "--n-mels", "32", "--threads", "1", "--no-progress", "--calibration", "off",
        "--epochs", "6", "--patience", "10"]
#: Every launch ends well within this (a hung rendezvous fails the test, not the suite).
TIMEOUT_S = 300


def _torchrun(tmp_path, *args: str) -> subprocess.CompletedProcess:
    """``aslip train`` on two ranks."""
    env = dict(os.environ, OMP_NUM_THREADS="1")
    head = [sys.executable, "-m", "torch.distributed.run", "--standalone",
            "--nproc_per_node", "2", "-m", "aslip_ros.cli"]
    return subprocess.run(head + ["train", *args, *ARGS], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=TIMEOUT_S)


def _one(*args: str) -> int:
    """``aslip train`` in this process."""
    from aslip_ros import cli
    return cli.main(["train", *args, *ARGS])


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return make_synthetic_dataset(tmp_path_factory.mktemp("ddp") / "ds", n_trials=12,
                                  induced="robot", seed=4)


def _val(path) -> dict:
    return load_checkpoint(path).meta["provenance"]["metrics"]["val"]


def test_two_processes_train_within_the_seed_spread_of_one(dataset, tmp_path):
    one = []
    for seed in (0, 1, 2):
        out = tmp_path / f"one{seed}.pt"
        assert _one("--dataset", str(dataset), "--stage", "scratch", "--seed", str(seed),
                    "--out", str(out)) == 0
        one.append(_val(out))
    two = tmp_path / "two.pt"
    got = _torchrun(tmp_path, "--dataset", str(dataset), "--stage", "scratch", "--out",
                    str(two))
    assert got.returncode == 0, got.stdout[-2000:] + got.stderr[-2000:]
    assert got.stdout.count("wrote ") == 1           # rank 0 alone writes and prints
    meta = load_checkpoint(two).meta
    assert meta["provenance"]["training"]["epochs_run"] == 6
    for key in ("direction_mae_deg", "magnitude_rmse_mm", "detection_accuracy"):
        seeds = [m[key] for m in one]
        spread = max(seeds) - min(seeds)
        assert min(seeds) - spread <= _val(two)[key] <= max(seeds) + spread, (key, seeds)


def test_two_processes_choose_the_recipe_one_chooses(dataset, tmp_path):
    picks = []
    for procs in (1, 2):
        out = tmp_path / f"auto{procs}.pt"
        args = ("--dataset", str(dataset), "--recipes", "scratch,svm", "--time-budget", "600",
                "--out", str(out))
        if procs == 1:
            assert _one(*args) == 0
        else:
            got = _torchrun(tmp_path, *args)
            assert got.returncode == 0, got.stdout[-2000:] + got.stderr[-2000:]
        picks.append(load_checkpoint(out).meta["provenance"]["selection"]["winner"])
        assert (tmp_path / f"auto{procs}.pt.selection.md").is_file()
    assert picks[0] == picks[1]


def test_a_stage_that_trains_in_one_process_is_refused_under_torchrun(
        dataset, tmp_path, monkeypatch, capsys):
    """The environment torchrun gives a rank, here for a group of one: ``aslip train`` joins
    it, refuses the stages that train in one process, writes nothing and leaves the group."""
    import socket

    import torch.distributed as dist
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    for k, v in {"RANK": "0", "WORLD_SIZE": "1", "LOCAL_RANK": "0",
                 "MASTER_ADDR": "127.0.0.1", "MASTER_PORT": str(port)}.items():
        monkeypatch.setenv(k, v)
    joined, init = [], dist.init_process_group

    def spied(*a, **k):
        joined.append(a)
        return init(*a, **k)
    monkeypatch.setattr(dist, "init_process_group", spied)
    for stage in ("svm", "stream"):
        out = tmp_path / f"{stage}.pt"
        assert _one("--dataset", str(dataset), "--stage", stage, "--out", str(out)) != 0
        assert "trains in one process" in capsys.readouterr().err
        assert not out.exists() and not dist.is_initialized()
    assert joined == [("gloo",), ("gloo",)]


def test_on_gpus_the_group_carries_cpu_tensors_too(monkeypatch):
    """On an H200, torchrun with NCCL failed at the first epoch: rank 0's clock (``now``)
    is a CPU tensor, which NCCL cannot carry ("No backend type associated with device type
    cpu"). The group on GPUs is NCCL for CUDA tensors and gloo for CPU ones."""
    import torch
    import torch.distributed as dist

    from aslip_ros.learn.training import distributed
    got = []
    monkeypatch.setattr(dist, "is_initialized", lambda: False)
    monkeypatch.setattr(dist, "init_process_group", lambda backend: got.append(backend))
    monkeypatch.setattr(torch.cuda, "set_device", lambda i: None)
    for k, v in {"RANK": "0", "WORLD_SIZE": "1", "LOCAL_RANK": "0", "MASTER_ADDR": "x",
                 "MASTER_PORT": "1"}.items():
        monkeypatch.setenv(k, v)
    distributed.setup(torch.device("cuda"))
    distributed.setup(torch.device("cpu"))
    assert got == ["cuda:nccl,cpu:gloo", "gloo"]
