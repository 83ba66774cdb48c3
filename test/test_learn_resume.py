"""``aslip train --resume`` (#38): an interrupted run goes on from its last completed epoch.

The interruption is a KeyboardInterrupt out of an epoch (what Ctrl-C or a lost session
gives); the state on disk is the one the last completed epoch wrote.
"""

from __future__ import annotations

import argparse
import json

import pytest
import torch

from aslip_ros.learn.checkpoint import load_checkpoint
from aslip_ros.learn.models import aslip_cnn_fit
from aslip_ros.learn.synthetic import make_synthetic_dataset
from aslip_ros.learn.training import cli as train_cli
from aslip_ros.learn.training.resume import resume_dir

SMALL = ["--width", "8", "--depth", "2", "--temporal-channels", "32", "--head-hidden", "16",
         "--n-mels", "32", "--threads", "1", "--no-progress", "--calibration", "off"]


def _train(argv) -> int:
    p = argparse.ArgumentParser()
    train_cli.add_arguments(p)
    return train_cli.run(p.parse_args(argv))


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return make_synthetic_dataset(tmp_path_factory.mktemp("resume") / "ds", n_trials=9,
                                  induced="robot", seed=3)


def _interrupt_after(monkeypatch, epochs: int) -> None:
    """The next run's epoch number ``epochs`` (counted from 0 in this process) is cut."""
    real, calls = aslip_cnn_fit._train_epoch, []

    def cut(*args, **kw):
        calls.append(1)
        if len(calls) > epochs:
            raise KeyboardInterrupt
        return real(*args, **kw)
    monkeypatch.setattr(aslip_cnn_fit, "_train_epoch", cut)


def test_a_resumed_run_ends_with_the_weights_of_an_uninterrupted_one(
        dataset, tmp_path, monkeypatch, capsys):
    args = ["--dataset", str(dataset), "--stage", "scratch", "--epochs", "4",
            "--patience", "10", "--seed", "2"] + SMALL
    assert _train(args + ["--out", str(tmp_path / "whole.pt")]) == 0
    assert not resume_dir(tmp_path / "whole.pt").exists()      # a finished call: none left

    out = tmp_path / "cut.pt"
    with monkeypatch.context() as m:
        _interrupt_after(m, 2)
        with pytest.raises(KeyboardInterrupt):
            _train(args + ["--out", str(out)])
    assert not out.exists() and (resume_dir(out) / "scratch.pt").is_file()
    capsys.readouterr()
    assert _train(args + ["--out", str(out), "--resume"]) == 0
    said = capsys.readouterr().out
    assert "resumed from" in said and "after epoch 1 " in said, said
    whole, cut = load_checkpoint(tmp_path / "whole.pt"), load_checkpoint(out)
    for k in whole.tensors:
        assert torch.equal(whole.tensors[k], cut.tensors[k]), k
    train = [cut.meta["provenance"]["training"], whole.meta["provenance"]["training"]]
    assert [t["epochs_run"] for t in train] == [4, 4]
    assert train[0]["best_epoch"] == train[1]["best_epoch"]
    assert not resume_dir(out).exists()


def test_another_runs_state_and_nothing_to_resume_are_refused(
        dataset, tmp_path, monkeypatch, capsys):
    args = ["--dataset", str(dataset), "--stage", "scratch", "--epochs", "3"] + SMALL
    out = str(tmp_path / "m.pt")
    assert _train(args + ["--out", out, "--resume"]) == 1
    assert "holds no interrupted run" in capsys.readouterr().err
    with monkeypatch.context() as m:
        _interrupt_after(m, 1)
        with pytest.raises(KeyboardInterrupt):
            _train(args + ["--out", out, "--seed", "1"])
    assert _train(args + ["--out", out, "--seed", "7", "--resume"]) == 1
    err = capsys.readouterr().err
    assert "is the state of another run" in err and "config" in err
    assert _train(args + ["--out", out, "--stage", "svm", "--resume"]) == 1
    assert "trains in one go" in capsys.readouterr().err


def test_the_recipe_choice_goes_on_from_its_jobs_states(
        dataset, tmp_path, monkeypatch, capsys):
    """--stage auto: the candidates' jobs load their states, and the budget counts the
    interrupted call's time."""
    out = tmp_path / "auto.pt"
    args = ["--dataset", str(dataset), "--out", str(out), "--recipes", "scratch,svm",
            "--epochs", "3", "--time-budget", "600"] + SMALL
    with monkeypatch.context() as m:
        _interrupt_after(m, 2)
        with pytest.raises(KeyboardInterrupt):
            _train(args)
    saved = sorted(p.name for p in resume_dir(out).iterdir())
    assert "run.json" in saved and any(n.startswith("scratch") for n in saved), saved
    spent = json.loads((resume_dir(out) / "run.json").read_text())["spent_s"]
    capsys.readouterr()
    assert _train(args + ["--resume"]) == 0
    assert "resumed from" in capsys.readouterr().out
    sel = load_checkpoint(out).meta["provenance"]["selection"]
    assert sel["wall_s"] >= spent
    assert not resume_dir(out).exists()
