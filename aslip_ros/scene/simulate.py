"""Record simulated scenarios to rosbag2 (mcap) bags: library and ``aslip simulate``.

Each trial is one bag directory ``<out>/<trial_id>/`` holding the documented topics
(``/aslip/audio``, ``/aslip/mocap/finger``, ``/aslip/mocap/object``,
``/aslip/robot/tcp_pose``, ``/aslip/metadata``) and the metadata in ``custom_data``. The
scene is streamed block by block into the bag writer, so memory stays bounded whatever the
duration.

Seeds: the seed of trial ``i`` of (kind, object, condition) is derived from ``--seed`` and
those names only. Layout and pad are left out on purpose: the same trial recorded with
another microphone layout or pad has the same motion, so layout and pad comparisons are
paired.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
import zlib
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from aslip_ros.data.bags import BagError, BagReader, BagWriter

from . import scenarios
from .world import World

KINDS = {"robot": "robot_induced", "external": "external_induced", "pivot": "gravity_pivot"}
#: Trial-id prefix of each kind.
_PREFIX = {"robot": "rob", "external": "ext", "pivot": "piv"}
DEFAULT_START_NS = 1_700_000_000_000_000_000   # a fixed ROS time so bags are reproducible
DEFAULT_BLOCK_FRAMES = 480
#: Scene variants (docs/scene.md, ``scene.variants.VARIANTS``): wider per-grasp coupling,
#: one-sided slip, off-centre contact, confounders without slip, a lab's motion capture, a
#: 44.1 kHz sound card, another loudness-speed exponent per object, a background that is
#: not common mode.
VARIANTS = ("coupling", "one_sided", "contact", "confounders", "mocap", "rate", "speed",
            "path")


#: Metadata that simulate records only when its option is given.
_OPTIONAL_METADATA = ("twist_fraction", "variant", "robot_noise_gain", "one_sided_heading_deg")
#: How a one-sided simulation gives its trials their preferred slip directions: each drawn
#: from its seed, or spread evenly round the circle over the trials (``even_headings``).
HEADINGS = ("random", "even")


def even_headings(n: int, seed: int) -> np.ndarray:
    """``n`` preferred slip directions [rad, in -pi..pi] evenly round the circle, 360/n
    degrees apart from an angle drawn from ``seed``, in an order drawn from it too (so no
    object or condition of the plan owns one side)."""
    rng = np.random.default_rng([int(seed), 0x4EAD])
    start = rng.uniform(0.0, 2.0 * np.pi / n)
    angles = start + 2.0 * np.pi * rng.permutation(n) / n
    return np.angle(np.exp(1j * angles))


def trial_seed(base_seed: int, kind: str, object: str, condition: str, index: int) -> int:
    """Deterministic per-trial seed (independent of layout and pad, see module docstring)."""
    key = f"{kind}/{object}/{condition}/{index}".encode()
    return int((int(base_seed) * 1_000_003 + zlib.crc32(key)) % (2**31 - 1))


def _check_noise_range(low: float, high: float) -> None:
    if not (0.0 < low <= high and math.isfinite(high)):
        raise ValueError(f"robot noise range must satisfy 0 < low <= high, got ({low}, {high})")


def robot_noise_gain(seed: int, low: float, high: float) -> float:
    """The arm's loudness of the trial with scenario seed ``seed``: a factor on
    ``Acoustics.robot_level``, log-uniform in [low, high] and drawn from that seed alone (so
    the same trial gets the same arm whatever else the set holds)."""
    _check_noise_range(low, high)
    u = np.random.default_rng([int(seed), 0xA7B0]).uniform()
    return float(math.exp(math.log(low) + u * (math.log(high) - math.log(low))))


def record_world(world: Any, path: str | Path, *, block_frames: int = DEFAULT_BLOCK_FRAMES,
                 start_ns: int = DEFAULT_START_NS, overwrite: bool = False,
                 on_block=None, extra_metadata: dict | None = None) -> dict:
    """Stream ``world`` (anything with ``metadata()`` and ``stream(block_frames=)``) to a bag.

    ``on_block(seconds)`` is called after each block (progress). ``extra_metadata`` is
    added to the world's metadata. Returns counts written.
    """
    meta = dict(world.metadata())
    meta.update(extra_metadata or {})
    sample_rate = float(meta["sample_rate"])
    names = list(meta["channel_names"])
    layout = meta.get("layout", "")
    counts = {"audio": 0, "mocap": 0, "tcp": 0, "frames": 0}
    with BagWriter(path, metadata=meta, start_ns=start_ns, overwrite=overwrite) as bag:
        for chunk in world.stream(block_frames=block_frames):
            audio = chunk.audio
            bag.write_audio(chunk.t0, chunk.first_sample_index, audio, sample_rate, names,
                            layout)
            counts["audio"] += 1
            counts["frames"] += int(audio.shape[0])
            for s in chunk.mocap:
                bag.write_pose("finger", s.t, s.finger_pose)
                bag.write_pose("object", s.t, s.object_pose)
                counts["mocap"] += 1
            for t, pose in chunk.tcp:
                bag.write_pose("tcp", t, pose)
                counts["tcp"] += 1
            if on_block is not None:
                on_block(audio.shape[0] / sample_rate)
    counts["audio_s"] = counts["frames"] / sample_rate
    return counts


def plan_trials(kind: str, objects: Sequence[str | None], conditions: Sequence[str | None],
                trials: int, seed: int, layout: str | None, pad: str | None,
                duration_s: float) -> list[dict]:
    """The scenario keyword arguments of every trial, in a stable order."""
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {sorted(KINDS)}, got {kind!r}")
    if trials < 1:
        raise ValueError(f"trials must be >= 1, got {trials}")
    if not duration_s > 0:
        raise ValueError(f"duration must be positive, got {duration_s}")
    plan = []
    prefix = _PREFIX[kind]
    for obj in objects:
        for cond in conditions:
            for i in range(trials):
                kw: dict[str, Any] = {"duration_s": float(duration_s)}
                for key, value in (("object", obj), ("condition", cond), ("layout", layout),
                                   ("pad", pad)):
                    if value is not None:
                        kw[key] = value
                kw["seed"] = trial_seed(seed, kind, obj or "default", cond or "default", i)
                kw["trial_id"] = "-".join(
                    [prefix] + [v for v in (obj, cond) if v] + [f"{i:04d}"])
                plan.append(kw)
    return plan


def recorded_differently(path: Path, metadata: dict, duration_s: float) -> str:
    """How the bag at ``path`` differs from a trial with ``metadata`` and ``duration_s``
    ("" when it is that trial). Bags without a recorded duration are measured instead."""
    try:
        with BagReader(path) as r:
            old = r.read_metadata() or {}
            span_s = r.info.duration_ns * 1e-9
    except BagError as exc:
        return f"it cannot be read ({exc})"
    new = json.loads(json.dumps(metadata))
    diffs = [f"{k} {old.get(k)!r} != {v!r}" for k, v in new.items()
             if k != "duration_s" and old.get(k) != v]
    # What simulate adds only when asked for, and a bag recorded with it holds.
    diffs += [f"{k} {old[k]!r} != None" for k in _OPTIONAL_METADATA if k in old and k not in new]
    old_duration = old.get("duration_s")
    # Without a recorded duration, the messages span the trial less one block or sample.
    if (old_duration is None and abs(span_s - duration_s) > 0.1) or (
            old_duration is not None and old_duration != duration_s):
        diffs.insert(0, f"duration {old_duration or round(span_s, 2)!r} s != {duration_s!r} s")
    return "; ".join(diffs)


def _trials(kind: str, plan: list[dict], duration_s: float, variant: str | None,
            twist_fraction: float, sample_rate: float | None,
            robot_noise_range: tuple[float, float] | None, headings: str = "random",
            seed: int = 0) -> tuple[list, list[dict]]:
    """Each planned trial's world and the metadata simulate adds to its own (the options
    of :func:`simulate`, validated here)."""
    make = getattr(scenarios, KINDS[kind])
    if variant not in (None,) + VARIANTS:
        raise ValueError(f"variant must be one of {VARIANTS}, got {variant!r}")
    if twist_fraction and kind != "external":
        raise ValueError("twist_fraction applies to --kind external only")
    twist = {"twist_fraction": float(twist_fraction)} if twist_fraction else {}
    if sample_rate is not None and not (math.isfinite(sample_rate) and sample_rate >= 8000):
        raise ValueError(f"sample_rate must be at least 8000 Hz, got {sample_rate!r}")
    if robot_noise_range is not None:
        _check_noise_range(*robot_noise_range)
    if headings not in HEADINGS:
        raise ValueError(f"headings must be one of {HEADINGS}, got {headings!r}")
    if headings != "random" and variant != "one_sided":
        raise ValueError("headings apply to the one_sided variant only")
    heading = even_headings(len(plan), seed) if headings == "even" else [None] * len(plan)
    gains = [None if robot_noise_range is None else robot_noise_gain(kw["seed"],
                                                                     *robot_noise_range)
             for kw in plan]

    def scene(kw, gain, head):
        scn = make(**kw, **twist)
        if head is not None:
            scn = scn.with_(one_sided_heading_rad=float(head))
        if sample_rate is not None:
            scn = dataclasses.replace(scn, sample_rate=float(sample_rate))
        if gain is not None:
            ac = scn.acoustics
            scn = scn.with_(acoustics=dataclasses.replace(ac, robot_level=ac.robot_level * gain))
        return scn if variant is None else scenarios.VARIANTS[variant](scn)
    worlds = [World(scene(kw, g, h)) for kw, g, h in zip(plan, gains, heading)]
    extra = {"duration_s": float(duration_s), **twist}
    if variant is not None:
        extra["variant"] = variant
    extras = [extra if g is None else {**extra, "robot_noise_gain": round(g, 4)} for g in gains]
    extras = [ex if h is None else {**ex, "one_sided_heading_deg": round(math.degrees(h), 3)}
              for ex, h in zip(extras, heading)]
    return worlds, extras


def simulate(out_dir: str | Path, kind: str, *, objects: Sequence[str | None] = (None,),
             conditions: Sequence[str | None] = (None,), trials: int = 1,
             duration_s: float = 30.0, seed: int = 0, layout: str | None = None,
             pad: str | None = None, block_frames: int = DEFAULT_BLOCK_FRAMES,
             overwrite: bool = False, progress: bool = True,
             variant: str | None = None, twist_fraction: float = 0.0,
             sample_rate: float | None = None,
             robot_noise_range: tuple[float, float] | None = None,
             headings: str = "random") -> dict:
    """Simulate ``trials`` bags per (object, condition) into ``out_dir``.

    ``None`` for object/condition/layout/pad means the scenario's own default.
    ``twist_fraction`` (external only): share of the agent's slipping pushes that twist the
    object (``Scenario.twist_fraction``; recorded in the metadata when not 0).
    ``sample_rate``: the audio interface's rate [Hz] (None: the scenario's, 48 kHz).
    ``robot_noise_range``: (low, high): each trial's arm as loud as the scene's times a
    factor drawn per trial (:func:`robot_noise_gain`; recorded as ``robot_noise_gain``), so
    a model hears arms quieter and louder than one (None: every trial the scene's arm).
    ``headings`` (``variant="one_sided"`` only): ``"even"`` spreads the trials' preferred
    slip directions evenly round the circle (:func:`even_headings`; recorded as
    ``one_sided_heading_deg``), as a lab that slips the object every way over its session;
    ``"random"`` draws each from its trial's seed.
    Existing bags
    of the same trials are kept (so an interrupted run resumes) unless ``overwrite``; an
    existing bag recorded with other parameters (duration, layout, pad, seed, scene
    version...) is refused with a ValueError before anything is recorded, since keeping it
    would mix two recordings in one set. Returns a summary dict.
    """
    from tqdm import tqdm

    plan = plan_trials(kind, objects, conditions, trials, seed, layout, pad, duration_s)
    out = Path(out_dir)
    worlds, extras = _trials(kind, plan, duration_s, variant, twist_fraction, sample_rate,
                             robot_noise_range, headings, seed)
    if not overwrite:
        for kw, world, ex in zip(plan, worlds, extras):
            path = out / kw["trial_id"]
            why = path.exists() and recorded_differently(path, {**world.metadata(), **ex},
                                                         float(duration_s))
            if why:
                raise ValueError(f"{path} holds a bag recorded with other parameters ({why}); "
                                 "pass --overwrite to replace such bags, or another --out")
    out.mkdir(parents=True, exist_ok=True)
    summary = {"bags": [], "skipped": [], "audio_s": 0.0}
    t_start = time.perf_counter()
    with tqdm(total=len(plan) * duration_s, unit="s", desc=f"simulate {kind}",
              disable=not progress, leave=False,
              bar_format="{l_bar}{bar}| {n:.0f}/{total:.0f} s audio [{elapsed}<{remaining}]"
              ) as bar:
        for kw, world, ex in zip(plan, worlds, extras):
            path = out / kw["trial_id"]
            if path.exists() and not overwrite:
                summary["skipped"].append(str(path))
                bar.update(duration_s)
                continue
            counts = record_world(world, path, block_frames=block_frames, overwrite=overwrite,
                                  on_block=bar.update, extra_metadata=ex)
            summary["bags"].append(str(path))
            summary["audio_s"] += counts["audio_s"]
    summary["elapsed_s"] = time.perf_counter() - t_start
    return summary


def _csv(text: str | None) -> list[str | None]:
    if not text:
        return [None]
    return [v.strip() for v in text.split(",") if v.strip()]


def _range(text: str) -> tuple[float, float]:
    try:
        low, high = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected LOW,HIGH, got {text!r}") from None
    return low, high


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``aslip simulate``."""
    parser.add_argument("--kind", choices=sorted(KINDS), required=True,
                        help="robot: arm sweeps over a stationary probe (labels from robot "
                             "state); external: an agent pushes the held object (mocap); "
                             "pivot: gravity turns an object held off its centre of mass "
                             "whenever the grip relaxes (mocap)")
    parser.add_argument("--objects", help="comma-separated object names (scene default if "
                                          "omitted), e.g. chips_can,pla_rod")
    parser.add_argument("--conditions", help="comma-separated: robot_off, robot_stationary, "
                                             "robot_moving (scene default if omitted)")
    parser.add_argument("--layout", help="microphone layout, e.g. 4mic, 2mic_corners")
    parser.add_argument("--pad", help="pad: textured or smooth")
    parser.add_argument("--trials", type=int, default=1,
                        help="trials per object and condition (default %(default)s)")
    parser.add_argument("--duration", type=float, default=30.0,
                        help="seconds per trial (default %(default)s)")
    parser.add_argument("--seed", type=int, default=0, help="base seed (default %(default)s)")
    parser.add_argument("--block-frames", type=int, default=DEFAULT_BLOCK_FRAMES,
                        help="audio frames per AudioFrame message (default %(default)s)")
    parser.add_argument("-o", "--out", type=Path, required=True,
                        help="directory for the bags (one sub-directory per trial)")
    parser.add_argument("--variant", choices=VARIANTS, default=None,
                        help="held-out scene variant (docs/scene.md): +-6 dB coupling; 80 %% "
                             "of the slip one way; off-centre contact; confounders without "
                             "slip; a lab's motion capture; 44.1 kHz audio; another "
                             "loudness-speed exponent per object; the hand's and the arm's "
                             "noise by +-6 dB paths (default: the plain scene)")
    parser.add_argument("--twist-fraction", type=float, default=0.0,
                        help="external only: share of the agent's slipping pushes that twist "
                             "the object about the pad normal, half pure twists and half with "
                             "the push (default %(default)s: none)")
    parser.add_argument("--sample-rate", type=float, default=None,
                        help="the audio interface's rate in Hz (default: the scene's, 48000)")
    parser.add_argument("--robot-noise-range", type=_range, default=None, metavar="LOW,HIGH",
                        help="each trial's arm noise the scene's times a factor drawn per "
                             "trial, log-uniform in LOW..HIGH, e.g. 0.5,2 (default: the "
                             "scene's arm in every trial)")
    parser.add_argument("--headings", choices=HEADINGS, default="random",
                        help="--variant one_sided: each trial's preferred slip direction drawn "
                             "from its seed, or the trials' spread evenly round the circle "
                             "(default %(default)s)")
    parser.add_argument("--overwrite", action="store_true", help="replace existing bags")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    """Entry point of ``aslip simulate``."""
    try:
        summary = simulate(args.out, args.kind, objects=_csv(args.objects),
                           conditions=_csv(args.conditions), trials=args.trials,
                           duration_s=args.duration, seed=args.seed, layout=args.layout,
                           pad=args.pad, block_frames=args.block_frames,
                           overwrite=args.overwrite, progress=not args.no_progress,
                           variant=args.variant, twist_fraction=args.twist_fraction,
                           sample_rate=args.sample_rate,
                           robot_noise_range=args.robot_noise_range,
                           headings=args.headings)
    except (ValueError, OSError) as exc:
        print(f"aslip simulate: error: {exc}", file=sys.stderr)
        return 1
    rate = summary["audio_s"] / summary["elapsed_s"] if summary["elapsed_s"] > 0 else 0.0
    print(f"simulate: {len(summary['bags'])} bag(s) written to {args.out} "
          f"({summary['audio_s']:.0f} s of audio in {summary['elapsed_s']:.1f} s, "
          f"{rate:.0f}x real time), {len(summary['skipped'])} existing kept")
    return 0


if __name__ == "__main__":
    p = argparse.ArgumentParser(prog="aslip simulate")
    add_arguments(p)
    sys.exit(run(p.parse_args()))
