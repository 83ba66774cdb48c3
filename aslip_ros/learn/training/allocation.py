"""The time budget of ``aslip train --stage auto``, spent by successive halving.

Every CNN candidate is a ``Job`` that trains in slices (``models.aslip_cnn_fit.CnnJob``: the
optimiser, the random stream and the best epoch carry over between slices). ``successive_halving``
gives the surviving jobs equal slices round after round, ranks them with the selection
criterion on the validation trials and keeps the better half; the last survivor trains on
with the rest of the budget.

Why not Optuna's pruners: they decide for one trial at a time against the trials that
reported at the same rung before it, which suits many sampled trials run asynchronously.
Here a handful of named candidates train in turns on one machine and every round compares
all of them at once, in the few lines below, tested against jobs whose answer is known.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Any, Callable, Protocol

from aslip_ros.learn.training import distributed
from aslip_ros.learn.training.config import TrainConfig, TrainResult
from aslip_ros.learn.training.selection import METRICS, score

#: Share of the CNN time that the comparing rounds of successive halving spend; the last
#: survivor gets the rest.
EARLY_FRACTION = 0.5

#: A trainer that runs to the end in one call.
Trainer = Callable[[TrainConfig], TrainResult]


class Job(Protocol):
    """A training run the allocator can pause and resume (``models.aslip_cnn_fit.CnnJob``)."""

    @property
    def done(self) -> bool: ...            # no epoch left (early stopping, max epochs)

    @property
    def train_time_s(self) -> float: ...

    def advance(self, seconds: float) -> None: ...

    def val_metrics(self) -> dict[str, Any]: ...

    def val_predictions(self) -> dict[str, Any]: ...   # prob, v, w on the validation windows

    def result(self, stop_reason: str = "time_budget") -> TrainResult: ...


class OneShot:
    """A ``Job`` over a trainer that runs to the end in one call (the SVM, tests,
    experiments): its first ``advance`` trains with that slice as its time budget."""

    def __init__(self, trainer: Trainer, cfg: TrainConfig) -> None:
        self._trainer, self._cfg = trainer, cfg
        self._res: TrainResult | None = None
        self.train_time_s = 0.0

    @property
    def done(self) -> bool:
        return self._res is not None

    def advance(self, seconds: float) -> None:
        if self._res is None:
            t = time.perf_counter()
            self._res = self._trainer(dataclasses.replace(self._cfg, time_budget_s=seconds))
            self.train_time_s = time.perf_counter() - t

    def val_metrics(self) -> dict[str, Any]:
        return self.result().meta["provenance"]["metrics"]["val"]

    def val_predictions(self) -> dict[str, Any]:
        pred = self.result().val_pred
        if pred is None:
            raise ValueError("the trainer gave no validation predictions")
        return pred

    def result(self, stop_reason: str = "time_budget") -> TrainResult:
        if self._res is None:
            raise RuntimeError("the job has not run")
        return self._res


def halving_rounds(n: int) -> int:
    """Rounds that compare ``n`` candidates down to one (halving each time)."""
    return math.ceil(math.log2(n)) if n > 1 else 0


def successive_halving(jobs: dict[str, Job], budget_s: float, *,
                       others: dict[str, dict[str, Any]] | None = None,
                       clock: Callable[[], float] = distributed.now,
                       log: Callable[[str], None] = print
                       ) -> tuple[str, list[dict[str, Any]], list[dict[str, Any]]]:
    """Spend ``budget_s`` of wall time on ``jobs`` (in order) and return the survivor's name,
    one record per comparing round, and who trained on after the rounds (name, seconds).

    Each of ``halving_rounds(n)`` rounds gives every surviving job an equal slice of
    ``EARLY_FRACTION * budget_s / rounds``, scores them with ``score`` on their best epoch's
    validation metrics (``others``: finished candidates, the SVMs, scored beside them) and
    keeps the better half, ``ceil(k / 2)`` of ``k`` (ties: the earlier job). The survivor
    then trains until the budget is spent; if it has no epoch left first (early stopping),
    the next best of the last round goes on with the rest, and so on. A job with no epoch
    left stays in the comparison as it is; its slice is not spent."""
    if not jobs:
        raise ValueError("no job to allocate time to")
    t0 = clock()
    alive = list(jobs)
    rounds = halving_rounds(len(alive))
    records: list[dict[str, Any]] = []
    for k in range(rounds):
        round_s = EARLY_FRACTION * budget_s / rounds
        slice_s = round_s / len(alive)
        for name in alive:
            if not jobs[name].done:
                jobs[name].advance(slice_s)
        metrics = {n: jobs[n].val_metrics() for n in alive}
        scores = score({**(others or {}), **metrics})
        ranked = sorted(alive, key=lambda n: (scores[n], alive.index(n)))
        keep = ranked[:math.ceil(len(alive) / 2)]
        stopped = [n for n in alive if n not in keep]
        records.append({"round": k + 1, "slice_s": round(slice_s, 1),
                        "elapsed_s": round(clock() - t0, 1),
                        "scores": {n: round(scores[n], 4) for n in alive},
                        "val": {n: {m: metrics[n].get(m) for m in METRICS} for n in alive},
                        "kept": keep, "stopped": stopped})
        log(f"round {k + 1}/{rounds} ({slice_s:.0f} s each): "
            + ", ".join(f"{n} {scores[n]:.3f}" for n in ranked)
            + f"; going on: {', '.join(keep)}; stopped: {', '.join(stopped)}")
        alive = [n for n in alive if n in keep]
    winner = alive[0]
    # The rest to the survivor; what an early-stopped survivor leaves goes on to the next
    # best that can still train (the last round's losers first), not back to the clock.
    rest: list[dict[str, Any]] = []
    order = [winner] + [n for r in reversed(records)
                        for n in sorted(r["stopped"], key=lambda n: r["scores"][n])]
    for name in order:
        left = budget_s - (clock() - t0)
        if left <= 0:
            break
        if jobs[name].done:
            continue
        log(f"{name}: training on for the {left:.0f} s left")
        before = jobs[name].train_time_s
        jobs[name].advance(left)
        rest.append({"name": name, "seconds": round(jobs[name].train_time_s - before, 1)})
    return winner, records, rest
