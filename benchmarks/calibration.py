"""Per-grasp microphone calibration on the scene's coupling variants (docs/model.md).

``python -m benchmarks.calibration --out data/calib_exp`` renders externally
induced trials (one trial = one grasp) of two variants, both with per-grasp coupling of
+-``scenarios.COUPLING_DB`` per microphone:

- ``coupling``: pushes in all directions;
- ``one_sided``: 80 % of the pushes within +-30 deg of one direction per grasp.

It then measures (1) how well each calibration method recovers the true relative gains over
time, model-free, and (2) direction / magnitude / detection of the plain CNN and the plain
SVM given raw features (one window), calibrated features, or the true gains (oracle), with
bootstrap confidence intervals over test trials.

``--self-check`` measures the estimate's self-check instead (``CalibrationState.trusted``,
docs/model.md): constants fitted on default-scene grasps (arm moving and still), then on
held-out grasps of the default scene, the coupling variant and the path variant (the hand's
and the arm's noise by +-6 dB paths of their own), both arm conditions, the same seeds in
each scene: the share of grasps flagged untrustworthy and the RMS gain error of flagged and
unflagged grasps, at a few times after the grasp started (``<out>/self_check.json``).

Small on purpose (minutes of CPU): audio is rendered at 16 kHz, the stream's own rate for
the features, and labels are the scene's true mean slip velocity per 200 ms window (the
export path and its labels are tested elsewhere). Rendered features are cached in ``--out``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from aslip_ros.learn import baselines

from aslip_ros.learn.calibration import grasp as calibration

from aslip_ros.learn import stats
from aslip_ros.learn.features import LogMel
from aslip_ros.scene import OBJECTS, World, get_layout
from aslip_ros.scene.layouts import DEFAULT_LAYOUT
from aslip_ros.scene import scenarios as sc

RATE = 16000.0
WINDOW_S, HOP_S = 0.2, 0.1
EPSILON = 0.005
VARIANTS = ("coupling", "one_sided")
_SEED_BASE = {"coupling": 10000, "one_sided": 20000}


def scenario(variant: str, split: str, k: int, duration_s: float) -> sc.Scenario:
    seed = _SEED_BASE[variant] + (0 if split == "train" else 5000) + k
    scn = sc.external_induced(seed=seed, object=list(OBJECTS)[k % len(OBJECTS)],
                              duration_s=duration_s, sample_rate=RATE,
                              condition="robot_stationary")
    return sc.VARIANTS[variant](scn)


def render_trial(scn: sc.Scenario) -> dict[str, np.ndarray]:
    """Continuous log-mel frames, frame and window labels and the true gains of one grasp."""
    world = World(scn)
    chunks = list(world.stream(block_frames=1600))
    audio = np.concatenate([c.audio for c in chunks])
    v_rel = np.concatenate([c.v_rel for c in chunks])
    fcfg = baselines.baseline_features(RATE)
    frames = LogMel(fcfg, RATE)(audio)                               # (C, M, T)
    n_fft, hop = fcfg.n_fft, fcfg.hop
    centre = np.arange(frames.shape[2]) * hop + n_fft // 2
    frame_slip = np.hypot(*v_rel[centre].T) > EPSILON
    n_win, n_hop = int(WINDOW_S * RATE), int(HOP_S * RATE)
    starts = np.arange(0, audio.shape[0] - n_win + 1, n_hop)
    v = np.stack([v_rel[s:s + n_win].mean(axis=0) for s in starts]).astype(np.float32)
    return {"frames": frames.astype(np.float16), "frame_slip": frame_slip,
            "start_frame": (starts // hop).astype(np.int64), "v": v,
            "slip": np.hypot(*v.T) > EPSILON, "gain": world.synth.gain.astype(np.float64),
            "main_dir": np.float64(scn.one_sided_direction_rad)}


def load_split(out: Path, variant: str, split: str, n: int, duration_s: float,
               log=print, make=None, name: str | None = None) -> list[dict[str, np.ndarray]]:
    """``n`` rendered trials, cached in ``out``; ``make(k)`` builds trial ``k``'s scenario
    (default: :func:`scenario` of the variant), ``name`` names the cache file."""
    name = name or variant
    path = out / f"{name}-{split}-{n}x{duration_s:g}s.npz"
    if path.is_file():
        with np.load(path) as z:
            return [{k[len(f"{i}_"):]: z[k] for k in z.files if k.startswith(f"{i}_")}
                    for i in range(n)]
    t0 = time.time()
    make = make or (lambda k: scenario(variant, split, k, duration_s))
    trials = [render_trial(make(k)) for k in range(n)]
    out.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, **{f"{i}_{k}": v for i, t in enumerate(trials) for k, v in t.items()})
    tmp.replace(path)
    log(f"rendered {name}/{split}: {n} trials in {time.time() - t0:.0f} s")
    return trials


def fit(trials: list[dict], method: str) -> calibration.CalibrationConstants:
    names = get_layout(DEFAULT_LAYOUT).channel_names
    return calibration.fit_constants(
        [t["frames"].astype(np.float32) for t in trials], [t["frame_slip"] for t in trials],
        names, HOP_S / 10.0, method=method,
        true_offsets=[calibration.relative_log_gain(t["gain"]) for t in trials])


TIMES_S = (1.0, 2.0, 5.0, 10.0, 20.0, 30.0)


def gain_error(trials: list[dict], k: calibration.CalibrationConstants | None,
               times_s=TIMES_S) -> dict[str, float]:
    """RMS error [dB] of the estimated relative gains at given times after the grasp
    (``k`` None: no calibration, the error of assuming equal gains)."""
    err = {t: [] for t in times_s}
    for tr in trials:
        f = tr["frames"].astype(np.float32)
        ends = np.minimum((np.asarray(times_s) / 0.01).astype(int), f.shape[2])
        est = calibration.offsets_at(f, ends, k) if k is not None \
            else np.zeros((len(times_s), f.shape[0]))
        truth = calibration.relative_log_gain(tr["gain"])
        for t, e in zip(times_s, est):
            err[t].append(np.sqrt(np.mean((e - truth) ** 2)) * 10.0 / np.log(10.0))
    return {f"{t:g}s": float(np.sqrt(np.mean(np.square(v)))) for t, v in err.items()}


def windows(trials: list[dict], mode: str, k: calibration.CalibrationConstants | None = None
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Window features (n, C, M, T) with no / estimated / true gain removal, and labels."""
    xs, vs, ss, ts = [], [], [], []
    for i, tr in enumerate(trials):
        f = tr["frames"].astype(np.float32)
        n_t = 1 + (int(WINDOW_S * RATE) - 1024) // 160
        idx = tr["start_frame"][:, None] + np.arange(n_t)[None, :]
        x = np.transpose(f[:, :, idx], (2, 0, 1, 3))                # (W, C, M, T)
        if mode in ("calibrated", "calibrated_slip"):
            x = x - calibration.offsets_at(f, idx[:, -1] + 1, k[mode]).astype(np.float32)[
                :, :, None, None]
        elif mode == "oracle":
            x = x - calibration.relative_log_gain(tr["gain"]).astype(np.float32)[
                None, :, None, None]
        xs.append(x)
        vs.append(tr["v"])
        ss.append(tr["slip"])
        ts.append(np.full(x.shape[0], i))
    return np.concatenate(xs), np.concatenate(vs), np.concatenate(ss), np.concatenate(ts)


MODES = ("raw", "calibrated", "calibrated_slip", "oracle")


class _SlipNetModel:
    def __init__(self, net) -> None:
        self.net = net.eval()

    def predict(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        import torch
        with torch.no_grad():
            out = self.net(torch.from_numpy(np.asarray(x, dtype=np.float32)))
            d = torch.nn.functional.normalize(out.direction, dim=1, eps=1e-8)
            return (torch.sigmoid(out.logit).numpy().astype(np.float64),
                    (d * out.magnitude[:, None]).numpy().astype(np.float64))


def fit_slipnet(x: np.ndarray, v: np.ndarray, slip: np.ndarray, epochs: int = 25,
                seed: int = 0) -> _SlipNetModel:
    """The package's network (default size, 48 mels) trained from scratch with its losses
    (no smoothness term), Adam 1e-3 / weight decay 1e-4, batch 128, a fixed number of epochs:
    the architecture on equal terms with the plain CNN, not the documented two-stage recipe."""
    import torch
    from aslip_ros.learn.features import normalization_stats
    from aslip_ros.learn.models.aslip_cnn_loss import slip_loss
    from aslip_ros.learn.models.aslip_cnn import ModelConfig, SlipNet

    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    speed = np.hypot(*v.T)
    scale = float(np.median(speed[slip]))
    net = SlipNet(ModelConfig(n_channels=x.shape[1], n_mels=x.shape[2], speed_scale=scale))
    net.set_normalization(*normalization_stats(x))
    opt = torch.optim.Adam(net.parameters(), lr=1e-3, weight_decay=1e-4)
    xt, vt, st = (torch.from_numpy(np.asarray(a)) for a in (x, v, slip))
    net.train()
    for _ in range(epochs):
        order = torch.from_numpy(rng.permutation(x.shape[0]))
        for s in range(0, x.shape[0] - 1, 128):
            b = order[s:s + 128]
            opt.zero_grad()
            loss, _ = slip_loss(net(xt[b]), vt[b], st[b], speed_scale=scale)
            loss.backward()
            opt.step()
    return _SlipNetModel(net)


def model_rows(train: list[dict], test: list[dict], k, models=("svm", "cnn"),
               epochs: int = 25, modes=MODES, cnn_stride: int = 1, save: Path | None = None,
               log=print) -> dict[str, Any]:
    """Train and test each model on each input mode; ``cnn_stride`` thins the CNN's training
    windows (2: non-overlapping 200 ms windows), which halves its CPU time."""
    rows = {}
    early = np.concatenate([tr["start_frame"] * 0.01 + WINDOW_S <= 10.0 for tr in test])
    for mode in modes:
        xtr, vtr, str_, _ = windows(train, mode, k)
        xte, vte, ste, tte = windows(test, mode, k)
        for m in models:
            if mode == "calibrated_slip" and m != "svm":
                continue          # the failure mode is shown with the cheap model only
            t0 = time.time()
            if m == "svm":
                model = baselines.fit_plain_svm(xtr, vtr, str_)
            elif m == "slipnet":
                sel = slice(None, None, cnn_stride)
                model = fit_slipnet(xtr[sel], vtr[sel], str_[sel], epochs=epochs)
            else:
                sel = slice(None, None, cnn_stride)
                model = baselines.fit_plain_cnn(xtr[sel], vtr[sel], str_[sel], epochs=epochs)
            p, vel = model.predict(xte)
            res = stats.bootstrap_metrics(tte, p, vel, vte, ste, WINDOW_S, n_boot=500)
            if save is not None:
                np.savez(f"{save}-{m}-{mode}.npz", p=p, vel=vel, v=vte, slip=ste, trial=tte)
            res["train_s"] = time.time() - t0
            for name, sel in (("first_10s", early), ("after_10s", ~early)):
                res[f"direction_mae_deg_{name}"] = stats.compute_metrics(
                    p[sel], vel[sel], vte[sel], ste[sel], WINDOW_S).get("direction_mae_deg")
            rows[f"{m}/{mode}"] = res
            log(f"  {m}/{mode}: {_fmt(res)}  ({res['train_s']:.0f} s)")
    return rows


def _fmt(r: dict) -> str:
    def one(key: str, scale: float = 1.0) -> str:
        lo, hi = r.get(key + "_ci", (np.nan, np.nan))
        return f"{r[key] * scale:.1f} [{lo * scale:.1f}, {hi * scale:.1f}]"
    return (f"det {one('detection_accuracy', 100)} | dir {one('direction_mae_deg')} | "
            f"mag {one('magnitude_rmse_mm')}")


def paired(out: Path, variant: str, model: str, a: str, b: str,
           key: str = "direction_mae_deg") -> tuple[float, float, float] | None:
    """Paired trial bootstrap of ``key`` between input modes ``a`` and ``b`` (a - b)."""
    paths = [out / f"pred-{variant}-{model}-{m}.npz" for m in (a, b)]
    if not all(p.is_file() for p in paths):
        return None
    za, zb = (dict(np.load(p)) for p in paths)

    def metric(z):
        return lambda idx: stats.compute_metrics(z["p"][idx], z["vel"][idx], z["v"][idx],
                                                 z["slip"][idx], WINDOW_S)[key]
    return stats.paired_difference(za["trial"], metric(za), metric(zb), n_boot=500)


def summary(out: Path) -> None:
    """Print the paired differences that decide the comparisons in docs/model.md."""
    for variant in VARIANTS:
        for model in ("svm", "cnn", "slipnet"):
            for a, b in (("calibrated", "raw"), ("calibrated", "oracle"),
                         ("calibrated_slip", "raw"), ("calibrated", "calibrated_slip")):
                d = paired(out, variant, model, a, b)
                if d is not None:
                    print(f"{variant} {model}: direction MAE {a} - {b} = {d[0]:+.1f} deg "
                          f"[{d[1]:+.1f}, {d[2]:+.1f}]")


def one_sided_share(trials: list[dict]) -> float:
    """Share of slip windows whose direction lies within +-30 deg of the grasp's main one."""
    inside, total = 0, 0
    for tr in trials:
        v = tr["v"][tr["slip"]]
        d = np.angle(np.exp(1j * (np.arctan2(v[:, 1], v[:, 0]) - float(tr["main_dir"]))))
        inside += int(np.sum(np.abs(d) <= np.pi / 6))
        total += v.shape[0]
    return inside / max(total, 1)


CHECK_SCENES = ("default", "coupling", "path")
CHECK_CONDITIONS = ("robot_moving", "robot_stationary")
CHECK_TIMES_S = (2.0, 5.0, 10.0, 20.0)


def check_scenario(scene: str, condition: str, split: str, k: int,
                   duration_s: float) -> sc.Scenario:
    """Grasp ``k`` of the self-check: one seed per (condition, split, k) in every scene, so
    the scenes differ only in what the variant moves."""
    seed = 50000 + (0 if split == "train" else 5000) \
        + CHECK_CONDITIONS.index(condition) * 2500 + k
    scn = sc.external_induced(seed=seed, object=list(OBJECTS)[k % len(OBJECTS)],
                              duration_s=duration_s, sample_rate=RATE, condition=condition)
    return scn if scene == "default" else sc.VARIANTS[scene](scn)


def _rms(v) -> float | None:
    return float(np.sqrt(np.mean(np.square(v)))) if len(v) else None


def self_check(out: Path, n_train: int, n_test: int, duration_s: float,
               times_s=CHECK_TIMES_S, log=print) -> dict[str, Any]:
    """Flag rate and gain error [dB] of flagged / unflagged held-out grasps per scene,
    arm condition and time since the grasp started (see the module docstring)."""
    def split(scene, cond, name, n):
        return load_split(out, scene, name, n, duration_s, log=log,
                          make=lambda k: check_scenario(scene, cond, name, k, duration_s),
                          name=f"check-{scene}-{cond}")
    train = [t for c in CHECK_CONDITIONS for t in split("default", c, "train", n_train)]
    k = fit(train, "background")
    rep: dict[str, Any] = {"trust_spread_db": k.trust_spread_db, "train_grasps": len(train),
                           "test_grasps_per_row": n_test, "duration_s": duration_s, "rows": []}
    log(f"self-check threshold {k.trust_spread_db:.2f} dB (fitted on {len(train)} "
        f"default-scene grasps)")
    log("| scene | arm | t [s] | flagged | spread dB (median) | gain error dB: flagged | "
        "unflagged | all |")
    log("|---|---|---|---|---|---|---|---|")
    for scene in CHECK_SCENES:
        for cond in CHECK_CONDITIONS:
            per_t = {t: [] for t in times_s}
            for tr in split(scene, cond, "test", n_test):
                f = tr["frames"].astype(np.float32)
                truth = calibration.relative_log_gain(tr["gain"])
                state, done = calibration.CalibrationState(k), 0
                for t in times_s:
                    end = min(int(round(t / k.hop_s)), f.shape[2])
                    state.update(f[:, :, done:end])
                    done = end
                    err = np.sqrt(np.mean((state.offsets - truth) ** 2)) * 10 / np.log(10)
                    per_t[t].append((state.trusted, state.spread_db, err))
            for t, got in per_t.items():
                flagged = [e for ok, _, e in got if ok is False]
                passed = [e for ok, _, e in got if ok is not False]
                row = {"scene": scene, "condition": cond, "t_s": t, "grasps": len(got),
                       "converged": sum(ok is not None for ok, _, _ in got),
                       "flagged": len(flagged),
                       "spread_db_median": float(np.median([s for _, s, _ in got])),
                       "gain_error_db_flagged": _rms(flagged),
                       "gain_error_db_unflagged": _rms(passed),
                       "gain_error_db": _rms([e for _, _, e in got])}
                rep["rows"].append(row)

                def fmt(v):
                    return "-" if v is None else f"{v:.2f}"
                log(f"| {scene} | {cond.split('_')[1]} | {t:g} | {len(flagged)}/{len(got)} | "
                    f"{row['spread_db_median']:.2f} | {fmt(row['gain_error_db_flagged'])} | "
                    f"{fmt(row['gain_error_db_unflagged'])} | {fmt(row['gain_error_db'])} |")
    out.mkdir(parents=True, exist_ok=True)
    (out / "self_check.json").write_text(json.dumps(rep, indent=1))
    return rep


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="data/calib_exp")
    ap.add_argument("--train", type=int, default=20)
    ap.add_argument("--test", type=int, default=12)
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--epochs", type=int, default=25)
    ap.add_argument("--models", default="svm,cnn")
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--modes", default=",".join(MODES))
    ap.add_argument("--cnn-stride", type=int, default=1)
    ap.add_argument("--report", default="report.json")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--summary", action="store_true",
                    help="only print paired differences from saved predictions")
    ap.add_argument("--self-check", action="store_true",
                    help="only measure the calibration's self-check (--train grasps per arm "
                         "condition, --test per scene and condition)")
    a = ap.parse_args(argv)
    if a.summary:
        summary(Path(a.out))
        return 0
    if a.self_check:
        self_check(Path(a.out), a.train, a.test, a.duration,
                   tuple(t for t in CHECK_TIMES_S if t <= a.duration))
        return 0
    import torch
    torch.set_num_threads(a.threads)
    out = Path(a.out)
    report: dict[str, Any] = {}
    for variant in a.variants.split(","):
        train = load_split(out, variant, "train", a.train, a.duration)
        test = load_split(out, variant, "test", a.test, a.duration)
        rep: dict[str, Any] = {"one_sided_share_test": one_sided_share(test)}
        print(f"{variant}: slip windows within +-30 deg of the main direction: "
              f"{rep['one_sided_share_test']:.2f}")
        consts = {m: fit(train, m) for m in calibration.METHODS}
        rep["gain_error_db/none"] = gain_error(test, None)
        for m, k in consts.items():
            rep[f"gain_error_db/{m}"] = gain_error(test, k)
        for m in ("none",) + calibration.METHODS:
            e = rep[f"gain_error_db/{m}"]
            print(f"  gain error dB, {m:10s}: " + " ".join(f"{t} {v:.2f}" for t, v in e.items()))
        rep["models"] = model_rows(train, test, {"calibrated": consts["background"],
                                                 "calibrated_slip": consts["slip"]},
                                   tuple(a.models.split(",")), a.epochs,
                                   tuple(a.modes.split(",")), a.cnn_stride,
                                   save=out / f"pred-{variant}")
        report[variant] = rep
        (out / a.report).write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
