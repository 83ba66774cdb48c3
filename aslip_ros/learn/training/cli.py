"""``aslip train``: the command line over the stages (learn/training/train.py: a model's
own fit, the CNN's included, and the SVM), the recipe chosen on the user's data
(recipes.py) and the streaming estimator (stream.py).

Stages:
  auto      (default) train the candidate recipes within a time budget and keep the one
            best on the validation trials (learn/training/recipes.py, docs/model.md)
  pretrain  all weights on (robot-induced) data          -> a checkpoint to finetune from
  finetune  from ``--init``: encoder frozen, heads only  (externally-induced data)
  scratch   all weights, no initialisation               (e.g. "single mic, no pretrain")
  svm       the paper's SVM baseline
  stream    the causal streaming estimator (docs/streaming.md)
  <type>    a registered model type whose backend defines ``fit`` (docs/design.md)
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys

from aslip_ros.learn.coverage import of_windows, warning
from aslip_ros.learn.data_io import open_dataset
from aslip_ros.learn.features import FeatureConfig
from aslip_ros.learn.models.aslip_cnn import ModelConfig
from aslip_ros.learn.models.aslip_stream import StreamConfig
from aslip_ros.learn.models.registry import CNN
from aslip_ros.learn.models.svm import FEATURES, SvmConfig
from aslip_ros.learn.training import distributed
from aslip_ros.learn.training.config import (CALIBRATIONS, DEVICES, STAGES, TrainConfig,
                                             fit_stage, resolve_device)
from aslip_ros.learn.training.recipes import (DEFAULT_BUDGET_S, DEFAULT_RECIPES, RECIPES,
                                              run_selected)
from aslip_ros.learn.training.resume import RunStates
from aslip_ros.learn.training.stream import run_from_args
from aslip_ros.learn.training.data import split_windows
from aslip_ros.learn.training.train import train_backend, train_svm


def _csv(s: str | None) -> list[str] | None:
    return [x for x in s.split(",") if x] if s else None


def _add_auto_arguments(p: argparse.ArgumentParser) -> None:
    """The options of --stage auto (learn/training/recipes.py)."""
    p.add_argument("--pretrain-dataset", default=None,
                   help="--stage auto: a robot-induced dataset to pretrain the encoder on "
                        "(optional; the frozen/partial/unfrozen recipes need it)")
    p.add_argument("--recipes", default=None,
                   help="--stage auto: comma-separated candidates out of "
                        + ",".join(RECIPES) + " (default " + ",".join(DEFAULT_RECIPES) + ")")
    p.add_argument("--seeds", default="0",
                   help="--stage auto: training seeds of the scratch candidate")
    p.add_argument("--keep-candidates", action="store_true",
                   help="--stage auto: also write every candidate's checkpoint to "
                        "<out>.candidates/<name>.pt")


def _add_augmentation_arguments(p: argparse.ArgumentParser, d: TrainConfig) -> None:
    """Random gain and SpecAugment (learn/models/aslip_cnn_fit.py, ``augment``)."""
    p.add_argument("--gain-db", type=float, default=d.gain_db,
                   help="random whole-window gain augmentation, +/- dB")
    p.add_argument("--channel-gain-db", type=float, default=d.channel_gain_db,
                   help="extra random per-microphone gain augmentation, +/- dB")
    p.add_argument("--freq-mask", type=int, default=d.freq_mask,
                   help="SpecAugment: widest frequency mask in mel bins (-1: n_mels // 8; "
                        "default %(default)s, none: measured, the masks cost magnitude)")
    p.add_argument("--time-mask", type=int, default=d.time_mask,
                   help="SpecAugment: widest time mask in frames (default %(default)s)")


def add_arguments(p: argparse.ArgumentParser) -> None:
    d, m, f = TrainConfig(), ModelConfig(), FeatureConfig()
    p.add_argument("--dataset", required=True, help="dataset directory (aslip export)")
    p.add_argument("--stage", default="auto", metavar="{" + ",".join(STAGES) + ",<model_type>}",
                   help="auto: train the candidate recipes (--recipes) within "
                        "--time-budget and keep the best on the validation trials; "
                        "pretrain: the CNN on robot-induced data; finetune: the heads on "
                        "another set from --init (the paper's frozen encoder); scratch: "
                        "every weight on this dataset; svm: the paper's SVM baseline; "
                        "stream: the causal streaming estimator (docs/streaming.md); "
                        "<model_type>: a registered model's own training stage (its "
                        "backend's fit, docs/design.md)")
    p.add_argument("--init", default=None, help="checkpoint to finetune (--stage finetune)")
    _add_auto_arguments(p)
    p.add_argument("--device", choices=DEVICES, default=d.device,
                   help="where the network trains: auto (default: a CUDA GPU where torch "
                        "sees one, else the CPU), cuda, or cpu (the CPU's exact numbers)")
    p.add_argument("--out", required=True, help="checkpoint file to write")
    p.add_argument("--resume", action="store_true",
                   help="go on with an interrupted run of the same command from each CNN "
                        "job's last completed epoch (its state: <out>.resume/)")
    p.add_argument("--seed", type=int, default=d.seed, help="training seed")
    p.add_argument("--split-seed", type=int, default=d.split_seed,
                   help="seed of the by-trial split (keep fixed across training seeds)")
    p.add_argument("--epochs", type=int, default=d.epochs, help="maximum epochs")
    p.add_argument("--patience", type=int, default=d.patience, help="early-stopping epochs")
    p.add_argument("--average-last", type=float, default=d.average_last,
                   help="share of the final model's epochs, when chosen on folds (trained "
                        "without validation), whose weights are averaged (stochastic weight "
                        "averaging); 0: its last epoch's weights")
    p.add_argument("--time-budget", type=float, default=None,
                   help="seconds of training after which the best epoch is kept (default "
                        f"{d.time_budget_s:g}); --stage auto: the whole call's budget, "
                        f"spent by successive halving (default {DEFAULT_BUDGET_S:g})")
    p.add_argument("--batch-size", type=int, default=d.batch_size)
    p.add_argument("--lr", type=float, default=d.lr)
    p.add_argument("--weight-decay", type=float, default=d.weight_decay)
    p.add_argument("--noslip-ratio", type=float, default=d.noslip_ratio,
                   help="no-slip windows per slip window drawn each epoch")
    p.add_argument("--threads", type=int, default=d.threads, help="torch.set_num_threads")
    _add_augmentation_arguments(p, d)
    p.add_argument("--window", type=float, default=None,
                   help="window length in s; must equal the dataset's (checked)")
    p.add_argument("--channels", default=None, help="comma-separated channel names to use")
    p.add_argument("--induced", default=None, help="only trials with this 'induced' value")
    p.add_argument("--objects", default=None, help="comma-separated objects to keep")
    p.add_argument("--conditions", default=None, help="comma-separated conditions to keep")
    p.add_argument("--calibration", choices=CALIBRATIONS, default="background",
                   help="per-grasp microphone calibration fitted on the training trials and "
                        "stored in the checkpoint (docs/model.md); off: raw features "
                        "(default %(default)s; a finetune keeps its --init's)")
    p.add_argument("--cache-dir", default=None,
                   help="feature cache directory (default <dataset>/.feature_cache)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    g = p.add_argument_group("features")
    g.add_argument("--feature-rate", type=float, default=f.sample_rate)
    g.add_argument("--n-fft", type=int, default=f.n_fft)
    g.add_argument("--hop", type=int, default=f.hop)
    g.add_argument("--n-mels", type=int, default=f.n_mels)
    g.add_argument("--fmin", type=float, default=f.fmin)
    g.add_argument("--fmax", type=float, default=None)
    g = p.add_argument_group("model size")
    g.add_argument("--width", type=int, default=m.width)
    g.add_argument("--depth", type=int, default=m.depth)
    g.add_argument("--temporal-channels", type=int, default=m.temporal_channels)
    g.add_argument("--temporal-layers", type=int, default=m.temporal_layers)
    g.add_argument("--head-hidden", type=int, default=m.head_hidden)
    g.add_argument("--dropout", type=float, default=m.dropout)
    g.add_argument("--gate", choices=["softmax", "sigmoid"], default=m.gate)
    g.add_argument("--stream-context", type=int, default=StreamConfig.context,
                   help="--stage stream: how many of the newest 10 ms frames the streaming "
                        "net's embedding reads together (default %(default)s: the current "
                        "frame; its GRU carries the rest; docs/streaming.md)")
    g = p.add_argument_group("svm")
    g.add_argument("--svm-c", type=float, default=SvmConfig.C)
    g.add_argument("--svm-max-train", type=int, default=SvmConfig.max_train)
    g.add_argument("--svm-features", choices=FEATURES, default=SvmConfig.features,
                   help="--stage svm: band features (the paper's) or the time-averaged "
                        "log-mel of each channel (the CNN's features)")


def run(args: argparse.Namespace) -> int:
    """``aslip train``; under ``torchrun`` every rank runs it (learn/training/distributed.py)
    and rank 0 alone prints and writes."""
    try:
        distributed.setup(resolve_device(args.device))
    except (ValueError, RuntimeError) as exc:
        print(f"aslip train: error: {exc}", file=sys.stderr)
        return 1
    try:
        if distributed.is_main():
            return _run(args)
        with open(os.devnull, "w") as quiet, contextlib.redirect_stdout(quiet):
            return _run(args)
    finally:
        distributed.teardown()


def _run(args: argparse.Namespace) -> int:
    if args.time_budget is None and args.stage != "auto":
        args.time_budget = TrainConfig.time_budget_s
    if args.stage == "stream" and distributed.active():
        print("aslip train: error: --stage stream trains in one process: run it without "
              "torchrun", file=sys.stderr)
        return 1
    if args.stage == "stream":     # the causal streaming estimator (learn/training/stream.py)
        return run_from_args(args)
    try:
        backend = fit_stage(args.stage)
        if args.stage not in STAGES and backend is None:
            raise ValueError(f"--stage {args.stage!r} is none of {STAGES} nor a model type "
                             "with a training stage (its backend defines fit)")
        ds = open_dataset(args.dataset)
        if args.window is not None and abs(args.window - ds.window_s) > 1e-9:
            raise ValueError(f"--window {args.window} s but the dataset has "
                             f"{ds.window_s} s windows; export it with that window")
        cfg = TrainConfig(stage=args.stage, epochs=args.epochs, batch_size=args.batch_size,
                          lr=args.lr, weight_decay=args.weight_decay, patience=args.patience,
                          seed=args.seed, split_seed=args.split_seed,
                          average_last=args.average_last, noslip_ratio=args.noslip_ratio,
                          time_budget_s=args.time_budget or TrainConfig.time_budget_s,
                          gain_db=args.gain_db, channel_gain_db=args.channel_gain_db,
                          freq_mask=args.freq_mask, time_mask=args.time_mask,
                          threads=args.threads, progress=not args.no_progress,
                          calibration=args.calibration, device=args.device,
                          induced=args.induced, objects=tuple(_csv(args.objects) or ()) or None,
                          conditions=tuple(_csv(args.conditions) or ()) or None)
        fcfg = FeatureConfig(sample_rate=args.feature_rate, n_fft=args.n_fft, hop=args.hop,
                             n_mels=args.n_mels, fmin=args.fmin, fmax=args.fmax)
        svm_config = SvmConfig(C=args.svm_c, max_train=args.svm_max_train,
                               features=args.svm_features)
        model_options = dict(width=args.width, depth=args.depth,
                             temporal_channels=args.temporal_channels,
                             temporal_layers=args.temporal_layers,
                             head_hidden=args.head_hidden, dropout=args.dropout, gate=args.gate)
        cnn = args.stage == "auto" or (backend is not None and backend.model_type == CNN)
        if distributed.active() and not cnn:
            raise ValueError(f"--stage {args.stage} trains in one process: run it without "
                             "torchrun (the CNN's stages and --stage auto train across "
                             "processes)")
        if args.resume and not cnn:
            raise ValueError(f"--resume: --stage {args.stage} trains in one go; run it again")
        states = RunStates(args.out, args.resume) if cnn else None
        if args.stage == "auto":
            code = run_selected(args, ds, cfg, fcfg, model_options, svm_config, states)
            states.finished()
            return code
        if backend is not None:        # the CNN's stages and a plug-in's, through its fit
            options = dict(model_options=model_options, init=args.init,
                           cache_dir=args.cache_dir, state=states.job(args.stage)) \
                if states is not None else {}
            res = train_backend(backend, ds, cfg, feature_config=fcfg,
                                channels=_csv(args.channels), **options)
        else:
            res = train_svm(ds, cfg, feature_config=fcfg, channels=_csv(args.channels),
                            svm_config=svm_config)
    except (ValueError, FileNotFoundError) as exc:
        print(f"aslip train: error: {exc}", file=sys.stderr)
        return 1
    if not distributed.is_main():
        return 0
    # The slip directions the model learned from (learn/coverage.py). Pretraining teaches
    # the encoder only: its sweeps need not cover the plane, so it records without warning.
    cov = of_windows(ds, split_windows(ds, cfg)[0])
    res.meta["provenance"]["direction_coverage"] = cov
    if args.stage != "pretrain" and (note := warning(cov)):
        print(note)
    res.save(args.out)
    if states is not None:
        states.finished()
    val = res.meta["provenance"]["metrics"]["val"]
    print(f"wrote {args.out}: val detection {val.get('detection_accuracy', float('nan')):.3f}, "
          f"direction MAE {val.get('direction_mae_deg', float('nan')):.1f} deg, "
          f"magnitude RMSE {val.get('magnitude_rmse_mm', float('nan')):.2f} mm")
    if val.get("n_angular_labelled"):
        from aslip_ros.learn.evaluate import rotation_line
        print("val " + rotation_line(val))
    return 0
