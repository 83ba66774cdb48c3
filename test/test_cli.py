"""The `aslip` console command: installed into the venv, --help works."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from aslip_ros import cli
from conftest import ROOT, _ros_available


def test_help_lists_subcommands():
    parser = cli.build_parser()
    text = parser.format_help()
    for name in ("simulate", "export", "train", "evaluate", "check"):
        assert name in text


BENCHMARKS = ("ablation", "bench", "stability", "demo")


def test_the_benchmarks_are_no_subcommands_but_run_from_the_checkout(capsys):
    """ablation, bench, stability and demo left the installed package (benchmarks/ at the
    repository root): `make <name>`, that is `python -m benchmarks.<name>`."""
    from benchmarks import cli as bench_cli
    for name in BENCHMARKS:
        assert name not in cli.SUBCOMMANDS
        with pytest.raises(SystemExit) as exc:
            bench_cli.main(name, ["--help"])
        assert exc.value.code == 0
        assert f"usage: python -m benchmarks.{name}" in capsys.readouterr().out


def test_a_benchmark_refusing_its_input_is_one_line_as_a_subcommand(monkeypatch, capsys):
    import types
    from benchmarks import cli as bench_cli
    fake = types.SimpleNamespace(__doc__="A fake.", add_arguments=lambda p: None,
                                 run=lambda a: open("/nonexistent/dir/file", "w"))
    monkeypatch.setitem(sys.modules, "benchmarks.fake", fake)
    assert bench_cli.main("fake", []) == 1
    err = _lines(capsys.readouterr().err)
    assert len(err) == 1 and err[0].startswith("python -m benchmarks.fake: error:"), err
    with pytest.raises(SystemExit) as exc:
        bench_cli.main("fake", ["--no-such-option"])
    assert exc.value.code == 2


def test_a_benchmark_runs_as_the_makefile_runs_it(tmp_path):
    """`python -P -m benchmarks.<name>` with the root after the install on PYTHONPATH (the
    Makefile's BENCHMARK): `benchmarks` from the checkout, `aslip_ros` not from the source
    tree at the root (the install, with its generated messages, when one is sourced)."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p] + [str(ROOT)]))
    out = subprocess.run([sys.executable, "-P", "-m", "benchmarks.demo", "--trials", "0"],
                         cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 2 and "benchmarks.demo:" in out.stderr, out.stderr
    code = "import aslip_ros, benchmarks; print(aslip_ros.__file__); print(benchmarks.__file__)"
    out = subprocess.run([sys.executable, "-P", "-c", code], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    pkg, bench = out.stdout.split()
    assert Path(bench) == ROOT / "benchmarks" / "__init__.py"
    import aslip_ros
    assert pkg == aslip_ros.__file__, "the benchmarks see the aslip_ros the tests see"
    if _ros_available() is None:
        assert Path(pkg) != ROOT / "aslip_ros" / "__init__.py"


def test_console_script_runs():
    exe = Path(sys.executable).with_name("aslip")
    assert exe.exists(), "make setup installs the `aslip` command into the venv"
    out = subprocess.run([str(exe), "--help"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "usage: aslip" in out.stdout


def test_unknown_subcommand_is_an_error():
    out = subprocess.run([sys.executable, "-m", "aslip_ros.cli", "nonsense"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode != 0
    assert "invalid choice" in out.stderr


def _lines(text):
    return [ln for ln in text.strip().splitlines() if ln.strip()]


def test_train_with_too_few_trials_refuses_instead_of_calling_training_numbers_val(
        tmp_path, capsys):
    """Regression: with no validation trial, `aslip train` validated on the training set and
    printed those numbers labelled "val" (CNN and SVM alike)."""
    from aslip_ros.learn.synthetic import make_synthetic_dataset
    ds = make_synthetic_dataset(tmp_path / "ds", n_trials=2, duration_s=2.0)
    for stage in ("svm", "scratch"):
        rc = cli.main(["train", "--dataset", str(ds), "--stage", stage, "--out",
                       str(tmp_path / f"{stage}.pt"), "--epochs", "1", "--width", "4",
                       "--no-progress", "--threads", "1"])
        out = capsys.readouterr()
        err = _lines(out.err)
        assert rc == 1 and "val detection" not in out.out, (stage, out)
        assert len(err) == 1 and "no validation trials" in err[0] and str(ds) in err[0]
        assert "2 trial(s): 2 train, 0 val, 0 test" in err[0]
        assert not (tmp_path / f"{stage}.pt").exists()


def test_evaluate_on_an_empty_test_split_names_split_all(tmp_path, capsys):
    """Regression: evaluate failed on an empty test split without saying --split all."""
    from aslip_ros.learn.synthetic import make_synthetic_dataset
    big = make_synthetic_dataset(tmp_path / "big", n_trials=6, duration_s=2.0)
    small = make_synthetic_dataset(tmp_path / "small", n_trials=3, duration_s=2.0, seed=5)
    ckpt = tmp_path / "svm.pt"
    assert cli.main(["train", "--dataset", str(big), "--stage", "svm", "--out", str(ckpt),
                     "--no-progress", "--threads", "1"]) == 0
    capsys.readouterr()
    rc = cli.main(["evaluate", "--checkpoint", str(ckpt), "--dataset", str(small)])
    err = _lines(capsys.readouterr().err)
    assert rc == 1 and len(err) == 1 and "--split all" in err[0], err
    assert "3 trial(s): 2 train, 1 val, 0 test" in err[0]
    assert cli.main(["evaluate", "--checkpoint", str(ckpt), "--dataset", str(small),
                     "--split", "all"]) == 0


def test_exit_codes_are_one_rule_across_subcommands(tmp_path, capsys):
    """1: the command refused its input (one line on stderr); 2: the command line is wrong.
    Regression: simulate and export exited 1, train and evaluate 2, for the same failure."""
    missing = str(tmp_path / "missing")
    refused = {
        "export": ["export", missing, "-o", str(tmp_path / "ds"), "--no-progress"],
        "train": ["train", "--dataset", missing, "--out", str(tmp_path / "m.pt"),
                  "--no-progress"],
        "evaluate": ["evaluate", "--checkpoint", missing, "--dataset", missing],
        "simulate": ["simulate", "--kind", "robot", "--duration", "-1", "-o",
                     str(tmp_path / "b"), "--no-progress"],
    }
    for name, argv in refused.items():
        rc = cli.main(argv)
        err = _lines(capsys.readouterr().err)
        assert rc == 1 and len(err) == 1 and err[0].startswith(f"aslip {name}: error:"), (
            name, rc, err)
    for name in ("export", "train", "evaluate", "simulate"):
        with pytest.raises(SystemExit) as exc:
            cli.main([name, "--no-such-option"])
        assert exc.value.code == 2
    capsys.readouterr()


def test_a_refused_input_reaching_the_top_is_one_line(monkeypatch, capsys):
    import types
    fake = types.SimpleNamespace(add_arguments=lambda p: None,
                                 run=lambda a: open("/nonexistent/dir/file", "w"))
    monkeypatch.setattr(cli, "_load", lambda module: fake)
    assert cli.main(["export"]) == 1
    err = _lines(capsys.readouterr().err)
    assert len(err) == 1 and "aslip export: error:" in err[0] and "/nonexistent" in err[0]
    monkeypatch.setenv("ASLIP_DEBUG", "1")
    with pytest.raises(OSError):
        cli.main(["export"])


def test_train_help_documents_every_stage_and_its_default(capsys):
    from aslip_ros import cli
    from aslip_ros.learn.training.config import STAGES
    with pytest.raises(SystemExit):
        cli.main(["train", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    i = text.rindex("--stage {")          # the option, not the usage line
    doc = text[i:text.index("--init INIT", i)]
    assert "(default: auto)" in doc
    for stage in STAGES:
        assert f"{stage}:" in doc, stage
