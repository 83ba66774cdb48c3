"""Where methods fail: ``make stability`` (``python -m benchmarks.stability``).

The finetuned 4-microphone CNN and the SVM (both from the ablation's cache, trained there
when missing) are evaluated under one stressor at a time:

- ``robot_noise``: the scene's robot operating noise scaled 0..8x (arm moving, new trials);
- ``texture``: pad texture blended continuously from textured to smooth (texture line level
  and stick-slip click rate interpolated between the two pads of the scene), plus the
  scene's smooth pad itself; the models are trained on textured pads only;
- ``dead_mic``: 0..3 microphones replaced by their noise floor (dead), and one microphone
  exactly zero (disconnected), on the test split;
- ``slip_speed``: the test split binned by true slip speed around the threshold (5 mm/s);
- ``object_out``: each object left out of the finetuning (CNN heads / SVM), tested on it;
- ``gain_mismatch``: random per-microphone gains of +-g dB on the test split.

For each stressor a PNG (detection and direction MAE against the level, per method) and an
entry in ``stability.json`` naming the level where each method breaks down: detection
below 70 % or direction MAE above 30 degrees. Training stability: the default model trained
with several seeds (mean +- std of every metric).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from aslip_ros.util import write_json, write_text

from .common import (DataPlan, Log, Recipe, add_plan_arguments, plan_from_args, evaluate_cached,
                     paper_units, configured, train_cached, train_named)
from .stability_report import (DET_MIN_PCT, DIR_MAX_DEG, breakdown, plot_stressor,
                               stability_markdown)

STRESSORS = ("robot_noise", "texture", "dead_mic", "slip_speed", "object_out",
             "gain_mismatch")
ROBOT_NOISE_LEVELS = (0.0, 0.5, 1.0, 2.0, 4.0, 8.0)
TEXTURE_LEVELS = (1.0, 0.75, 0.5, 0.25, 0.0)
GAIN_DB = (0.0, 1.0, 3.0, 6.0, 10.0, 20.0)
SPEED_EDGES_MM_S = (0.0, 1.0, 2.5, 4.0, 5.0, 6.0, 7.5, 10.0, 20.0, 50.0, 1000.0)


# --- configuration ------------------------------------------------------------------------

@dataclass
class StabilityConfig:
    out: Path = Path("results/stability")
    data: DataPlan = field(default_factory=DataPlan)
    recipe: Recipe = field(default_factory=Recipe)
    ablation_out: Path = Path("results/ablation")
    stressors: tuple[str, ...] = STRESSORS
    seeds: tuple[int, ...] = (0, 1, 2)
    robot_noise_levels: tuple[float, ...] = ROBOT_NOISE_LEVELS
    texture_levels: tuple[float, ...] = TEXTURE_LEVELS
    gain_db: tuple[float, ...] = GAIN_DB
    render_objects: tuple[str, ...] = ("pla_rod", "glass_cleaner", "chips_can",
                                       "mustard_container", "cracker_box")
    render_trials: int = 1
    render_s: float = 10.0
    svm: bool = True
    force: bool = False

    @property
    def cache(self) -> Path:
        return Path(self.out) / "cache"


class Stability:
    def __init__(self, cfg: StabilityConfig, log: Log | None = None) -> None:
        from .ablation import Ablation, AblationConfig
        self.cfg = cfg
        self.log = log or Log("stability")
        cfg.data.log = self.log
        self._retrained: set[Path] = set()    # --force retrains each checkpoint once a run
        # The ablation's rows are this module's models: same cache, trained there if missing.
        self.abl = Ablation(AblationConfig(out=cfg.ablation_out, data=cfg.data,
                                           recipe=cfg.recipe), log=self.log)

    # --- models ---------------------------------------------------------------------------
    def models(self) -> dict[str, Path]:
        out = {"cnn": self.abl.finetuned("4mic")[0]}
        if self.cfg.svm:
            out["svm"] = self.abl._train("svm_4mic_w200", self.abl.ds("4mic", "finetune"),
                                         "svm")[0]
        return out

    def predictors(self):
        from aslip_ros.learn.inference.predictor import Predictor
        return {k: Predictor.from_checkpoint(p) for k, p in self.models().items()}

    # --- test data ------------------------------------------------------------------------
    def test_windows(self) -> dict[str, Any]:
        from aslip_ros.learn.data_io import open_dataset, select_windows
        ds = open_dataset(self.abl.ds("4mic", "finetune"))
        idx = select_windows(ds, "test", seed=self.cfg.recipe.split_seed)
        return {"audio": ds.window_audio(idx), "v": ds.velocity(idx), "slip": ds.slip(idx),
                "window_s": ds.window_s, "trial": ds.windows["trial"][idx]}

    @staticmethod
    def score(pred, audio: np.ndarray, v: np.ndarray, slip: np.ndarray,
              window_s: float) -> dict[str, Any]:
        from aslip_ros.learn.metrics import compute_metrics
        b = pred.predict_batch(audio)
        return paper_units(compute_metrics(b.probability, b.raw_velocity, v, slip, window_s,
                                           pred.threshold))

    # --- rendered stressors ---------------------------------------------------------------
    def rendered(self, name: str, acoustics, pad: str, condition: str) -> Path:
        """A dataset of new externally induced trials rendered with ``acoustics``."""
        from aslip_ros.data.export import ExportConfig, export
        from aslip_ros.scene.simulate import record_world
        from aslip_ros.scene import World, scenarios
        cfg = self.cfg
        base = Path(cfg.data.base) / "stability"
        ds_path = base / "datasets" / name
        if (ds_path / "manifest.json").is_file() and not cfg.force:
            return ds_path
        bag_root = base / "bags" / name
        self.log(f"rendering {name} ({len(cfg.render_objects) * cfg.render_trials} trials "
                 f"of {cfg.render_s:g} s)")
        for obj in cfg.render_objects:
            for i in range(cfg.render_trials):
                # Seeds no training trial uses; the same across levels, so levels are paired.
                seed = 900_000 + 100 * cfg.render_objects.index(obj) + i
                path = bag_root / f"ext-{obj}-{i:04d}"
                if path.exists():
                    continue
                scn = scenarios.external_induced(seed=seed, object=obj, layout="4mic",
                                                 pad=pad, condition=condition,
                                                 duration_s=cfg.render_s,
                                                 acoustics=acoustics)
                record_world(World(scn), path)
        export([bag_root], ds_path, ExportConfig(progress=False, overwrite=True))
        return ds_path

    def score_dataset(self, preds: dict, ds_path: Path) -> dict[str, dict]:
        from aslip_ros.learn.data_io import open_dataset
        ds = open_dataset(ds_path)
        idx = np.arange(len(ds))
        audio, v, slip = ds.window_audio(idx), ds.velocity(idx), ds.slip(idx)
        return {m: self.score(p, audio, v, slip, ds.window_s) for m, p in preds.items()}

    def robot_noise(self, preds: dict) -> dict[str, Any]:
        from aslip_ros.scene.physics import Acoustics
        base = Acoustics()
        levels = list(self.cfg.robot_noise_levels)
        res = []
        for k in levels:
            ac = replace(base, robot_level=base.robot_level * k)
            res.append(self.score_dataset(preds, self.rendered(
                f"robot_noise_x{k:g}", ac, "textured", "robot_moving")))
        return {"x_label": "robot noise level (x the scene's default)", "levels": levels,
                "results": res}

    def texture(self, preds: dict) -> dict[str, Any]:
        from aslip_ros.scene.physics import Acoustics
        base = Acoustics()
        levels: list[Any] = list(self.cfg.texture_levels)
        res = []
        for a in levels:
            # Blend: texture lines fade out and stick-slip clicks rise to the smooth pad's.
            ac = replace(base, line_level=base.line_level * a,
                         click_rate_slip_textured=base.click_rate_slip_textured * a
                         + base.click_rate_slip_smooth * (1.0 - a))
            res.append(self.score_dataset(preds, self.rendered(
                f"texture_{a:g}", ac, "textured", "robot_stationary")))
        levels.append("smooth pad")
        res.append(self.score_dataset(preds, self.rendered(
            "texture_smooth_pad", base, "smooth", "robot_stationary")))
        return {"x_label": "pad texture (1 = textured, 0 = blended to smooth)",
                "levels": levels, "results": res}

    # --- post-hoc stressors on the test split ---------------------------------------------
    def dead_mic(self, preds: dict, data: dict) -> dict[str, Any]:
        from aslip_ros.scene.physics import Acoustics
        floor = Acoustics().floor_rms
        audio = data["audio"]
        n, _, c = audio.shape
        rng = np.random.default_rng(5)
        levels: list[Any] = []
        res = []
        for k in range(c):
            x = audio.copy()
            for i in range(n):
                # Rotate which microphones die so every choice is represented equally.
                for j in range(k):
                    ch = (i + j) % c
                    x[i, :, ch] = floor * rng.standard_normal(x.shape[1]).astype(np.float32)
            levels.append(k)
            res.append({m: self.score(p, x, data["v"], data["slip"], data["window_s"])
                        for m, p in preds.items()})
        x = audio.copy()
        for i in range(n):
            x[i, :, i % c] = 0.0
        levels.append("1 disconnected (zeros)")
        res.append({m: self.score(p, x, data["v"], data["slip"], data["window_s"])
                    for m, p in preds.items()})
        return {"x_label": "dead microphones (noise floor only)", "levels": levels,
                "results": res}

    def gain_mismatch(self, preds: dict, data: dict) -> dict[str, Any]:
        audio = data["audio"]
        rng = np.random.default_rng(9)
        trials = np.unique(data["trial"])
        levels = list(self.cfg.gain_db)
        res = []
        for g in levels:
            # One gain per microphone and trial: a coupling difference, not a fluctuation.
            gains = rng.uniform(-1.0, 1.0, (trials.size, audio.shape[2])) * g
            per_win = gains[np.searchsorted(trials, data["trial"])]
            x = audio * (10.0 ** (per_win / 20.0))[:, None, :].astype(np.float32)
            res.append({m: self.score(p, x, data["v"], data["slip"], data["window_s"])
                        for m, p in preds.items()})
        return {"x_label": "per-microphone gain mismatch (+- dB)", "levels": levels,
                "results": res}

    def slip_speed(self, preds: dict, data: dict) -> dict[str, Any]:
        speed_mm = np.linalg.norm(data["v"], axis=1) * 1e3
        edges = SPEED_EDGES_MM_S
        levels, res = [], []
        outs = {m: p.predict_batch(data["audio"]) for m, p in preds.items()}
        from aslip_ros.learn.metrics import compute_metrics
        # Fast to slow: the harsh end of this stressor is the threshold region.
        for lo, hi in reversed(list(zip(edges[:-1], edges[1:]))):
            m = (speed_mm >= lo) & (speed_mm < hi)
            if not m.any():
                continue
            levels.append(f"{lo:g}-{hi:g}")
            res.append({k: paper_units(compute_metrics(
                b.probability[m], b.raw_velocity[m], data["v"][m], data["slip"][m],
                data["window_s"], preds[k].threshold)) for k, b in outs.items()})
        return {"x_label": "true slip speed (mm/s); threshold 5 mm/s", "levels": levels,
                "results": res}

    def object_out(self, preds: dict) -> dict[str, Any]:
        abl = self.abl
        ft_ds = abl.ds("4mic", "finetune")
        pre, _ = abl.pretrained("4mic")
        all_models = self.models()
        from aslip_ros.learn.data_io import open_dataset
        objects = sorted(set(t["object"] for t in open_dataset(ft_ds).trials))
        levels, res = [], []
        for obj in objects:
            others = [o for o in objects if o != obj]
            row: dict[str, Any] = {}
            trained = {"cnn": lambda: self._train(f"cnn_without-{obj}", ft_ds, "finetune",
                                                  init=pre, objects=others)}
            if "svm" in preds:
                trained["svm"] = lambda: self._train(f"svm_without-{obj}", ft_ds, "svm",
                                                     objects=others)
            for m, make in trained.items():
                try:
                    held = evaluate_cached(make(), ft_ds, f"only-{obj}", split="test",
                                           objects=[obj], split_seed=self.cfg.recipe.split_seed)
                    seen = evaluate_cached(all_models[m], ft_ds, f"only-{obj}", split="test",
                                           objects=[obj], split_seed=self.cfg.recipe.split_seed)
                except ValueError as exc:   # no test trial of this object
                    self.log(f"  {obj}: {exc}")
                    break
                row[m] = paper_units(held["overall"])
                row[f"{m}_seen"] = paper_units(seen["overall"])
            if row:
                levels.append(obj)
                res.append(row)
        return {"x_label": "object left out of finetuning (tested on it)",
                "levels": levels, "results": res, "categorical": True}

    def _train(self, name: str, dataset: Path, stage: str, **kw: Any) -> Path:
        return train_named(self.cfg.cache, name, dataset, stage, self.cfg.recipe,
                           force=self.cfg.force, trained=self._retrained, log=self.log,
                           **kw)[0]

    # --- training stability ---------------------------------------------------------------
    def seeds(self) -> dict[str, Any]:
        ft_ds = self.abl.ds("4mic", "finetune")
        pre_ds = self.abl.ds("4mic", "pretrain")
        runs = []
        for s in self.cfg.seeds:
            if s == self.cfg.recipe.seed:
                ckpt, info = self.abl.finetuned("4mic")
                pre_info = train_cached(self.abl.cfg.cache / "pre_4mic_w200.pt", pre_ds,
                                        "pretrain", self.cfg.recipe)
            else:
                pre = self.cfg.cache / f"pre_4mic_seed{s}.pt"
                self.log(f"seed {s}: pretrain + finetune")
                pre_info = train_cached(pre, pre_ds, "pretrain", self.cfg.recipe, seed=s,
                                        log=lambda m: self.log(f"  seed {s}: {m}"))
                ckpt = self.cfg.cache / f"ft_4mic_seed{s}.pt"
                info = train_cached(ckpt, ft_ds, "finetune", self.cfg.recipe, init=pre, seed=s,
                                    log=lambda m: self.log(f"  seed {s}: {m}"))
            m = paper_units(evaluate_cached(ckpt, ft_ds, "test",
                                            split_seed=self.cfg.recipe.split_seed)["overall"])
            runs.append({"seed": s, "test": m,
                         "pretrain_time_s": pre_info.get("train_time_s"),
                         "finetune_time_s": info.get("train_time_s"),
                         "pretrain_epochs": pre_info.get("epochs_run"),
                         "finetune_epochs": info.get("epochs_run")})
        summary = {}
        for k in ("det_pct", "dir_mae_deg", "mag_rmse_mm"):
            v = np.array([r["test"][k] for r in runs if r["test"].get(k) is not None])
            if v.size:
                summary[k] = {"mean": round(float(v.mean()), 3),
                              "std": round(float(v.std(ddof=1)) if v.size > 1 else 0.0, 3),
                              "min": float(v.min()), "max": float(v.max())}
        t = [(r["pretrain_time_s"] or 0) + (r["finetune_time_s"] or 0) for r in runs]
        return {"runs": runs, "summary": summary,
                "train_time_s": {"mean": float(np.mean(t)), "max": float(np.max(t))}}

    def prepare(self) -> None:
        """Render the stressor datasets and train the extra seeds (no ablation model needed)."""
        if "robot_noise" in self.cfg.stressors:
            self.robot_noise({})
        if "texture" in self.cfg.stressors:
            self.texture({})
        ft_ds, pre_ds = self.abl.ds("4mic", "finetune"), self.abl.ds("4mic", "pretrain")
        for s in self.cfg.seeds:
            if s != self.cfg.recipe.seed:
                self.log(f"seed {s}: pretrain + finetune")
                pre = self.cfg.cache / f"pre_4mic_seed{s}.pt"
                train_cached(pre, pre_ds, "pretrain", self.cfg.recipe, seed=s,
                             log=lambda m: self.log(f"  seed {s}: {m}"))
                train_cached(self.cfg.cache / f"ft_4mic_seed{s}.pt", ft_ds, "finetune",
                             self.cfg.recipe, init=pre, seed=s,
                             log=lambda m: self.log(f"  seed {s}: {m}"))

    # --- everything -----------------------------------------------------------------------
    def run(self) -> dict[str, Any]:
        t0 = time.perf_counter()
        cfg = self.cfg
        # Work that needs none of the ablation's models first, so this can run beside a
        # ``make ablation`` that is still training them.
        self.prepare()
        preds = self.predictors()
        data = None
        out: dict[str, Any] = {"criteria": {"det_min_pct": DET_MIN_PCT,
                                            "dir_max_deg": DIR_MAX_DEG},
                               "stressors": {}}
        for name in cfg.stressors:
            self.log(f"stressor {name}")
            if name in ("dead_mic", "gain_mismatch", "slip_speed") and data is None:
                data = self.test_windows()
            fn: Callable = getattr(self, name)
            sweep = fn(preds, data) if name in ("dead_mic", "gain_mismatch", "slip_speed") \
                else fn(preds)
            methods = sorted({m for r in sweep["results"] for m in r
                              if not m.endswith("_seen")})
            sweep["breakdown"] = {
                m: breakdown(sweep["levels"],
                             [r.get(m, {}).get("det_pct") for r in sweep["results"]],
                             [r.get(m, {}).get("dir_mae_deg") for r in sweep["results"]])
                for m in methods}
            if sweep.get("categorical"):
                sweep["failing"] = {
                    m: [lvl for lvl, r in zip(sweep["levels"], sweep["results"])
                        if breakdown([lvl], [r.get(m, {}).get("det_pct")],
                                     [r.get(m, {}).get("dir_mae_deg")])]
                    for m in methods}
            out["stressors"][name] = sweep
            plot_stressor(name, sweep, cfg.out / f"{name}.png")
            write_json(cfg.out / "stability.json", out)
        if cfg.seeds:
            self.log(f"training stability: seeds {cfg.seeds}")
            out["training_seeds"] = self.seeds()
        out["elapsed_s"] = round(time.perf_counter() - t0, 1)
        write_json(cfg.out / "stability.json", out)
        write_text(cfg.out / "stability.md", stability_markdown(out))
        self.log(f"wrote {cfg.out} ({out['elapsed_s'] / 60:.1f} min)")
        return out


# --- CLI ----------------------------------------------------------------------------------

def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, default=Path("results/stability"))
    p.add_argument("--data", type=Path, default=Path("data"))
    p.add_argument("--scale", default="default", choices=["tiny", "default", "paper"])
    p.add_argument("--preset-finetune", action="store_true")
    p.add_argument("--ablation-out", type=Path, default=Path("results/ablation"),
                   help="the ablation's output (its cache holds the models)")
    p.add_argument("--stressors", default=",".join(STRESSORS))
    p.add_argument("--seeds", default="0,1,2", help="training seeds ('' to skip)")
    p.add_argument("--no-svm", action="store_true")
    add_plan_arguments(p, "tiny scale, few levels, 2 epochs")


def config_from_args(args: argparse.Namespace) -> StabilityConfig:
    quick = args.quick
    data, recipe = plan_from_args(args, svm_max_train=400 if quick else 4000)
    stressors = tuple(x for x in args.stressors.split(",") if x)
    bad = set(stressors) - set(STRESSORS)
    if bad:
        raise ValueError(f"unknown stressors {sorted(bad)}; choose from {STRESSORS}")
    if args.synthetic:
        # Synthetic data has no scene to re-render.
        stressors = tuple(s for s in stressors if s not in ("robot_noise", "texture"))
    seeds = tuple(int(x) for x in args.seeds.split(",") if x.strip())
    kw: dict[str, Any] = {}
    if quick:
        kw = dict(robot_noise_levels=(0.0, 4.0), texture_levels=(1.0, 0.0),
                  gain_db=(0.0, 10.0), render_objects=("chips_can",), render_s=3.0)
    return StabilityConfig(out=args.out, data=data, recipe=recipe,
                           ablation_out=args.ablation_out, stressors=stressors, seeds=seeds,
                           svm=not args.no_svm, force=args.force, **kw)


def run(args: argparse.Namespace) -> int:
    cfg = configured("stability", args, config_from_args)
    if cfg is None:
        return 2
    Stability(cfg).run()
    print((cfg.out / "stability.md").read_text())
    return 0


if __name__ == "__main__":
    from benchmarks.cli import main
    sys.exit(main("stability"))
