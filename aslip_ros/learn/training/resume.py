"""Going on with an interrupted ``aslip train`` (``--resume``, #38).

Every CNN job of a call (a fixed stage's one; with ``--stage auto`` each candidate's, per
fold, the shared pretraining and the final models) writes its state after each completed
epoch to ``<out>.resume/<job>.pt``: the weights, the optimiser, the best epoch so far, the
history, the time trained and both random streams (numpy's and torch's). With ``--resume``
each job, built again as before, loads its state and goes on from its last completed
epoch: a run bounded by epochs ends with the weights an uninterrupted run gives (tested),
and a time budget counts the time already spent (``run.json``: the call's seconds so far).
A job's state records what the job was built from (stage, seeds, split, dataset, channels,
features, model); a state from another run is refused, naming the difference. A call that
finishes removes the directory; a new call without ``--resume`` starts afresh.

The SVMs and the streaming estimator train in seconds to minutes and are trained again.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path
from typing import Any

import torch

from aslip_ros.learn.training import distributed
from aslip_ros.util import atomic_path, read_json, write_json

SUFFIX = ".resume"
RUN_FILE = "run.json"
#: What a resumed call may change of a job's config: the budget (to extend it), where and
#: on how many threads it trains, the progress bars.
RESUME_FREE = ("time_budget_s", "threads", "device", "progress")


def resume_dir(out: str | os.PathLike) -> Path:
    """Where the jobs of the call writing ``out`` keep their state."""
    return Path(f"{out}{SUFFIX}")


class RunStates:
    """The state files of one ``aslip train`` call; ``resume``: go on from them."""

    def __init__(self, out: str | os.PathLike, resume: bool) -> None:
        self.dir = resume_dir(out)
        self.resume = resume
        if resume and not (self.dir / RUN_FILE).is_file():
            raise ValueError(f"--resume: {self.dir} holds no interrupted run of {out} "
                             "(run the same command without --resume)")
        # Under torchrun rank 0 alone writes; every rank reads (learn/training/distributed).
        self.writes = distributed.is_main()
        if self.writes and not resume and self.dir.exists():
            shutil.rmtree(self.dir)         # a new run starts afresh
        if self.writes:
            self.dir.mkdir(parents=True, exist_ok=True)
        self.spent_before_s = float(read_json(self.dir / RUN_FILE)["spent_s"]) \
            if resume else 0.0
        self._t0 = time.perf_counter()
        self._note()

    def spent_s(self) -> float:
        """Seconds of this call so far, the interrupted runs' included."""
        return self.spent_before_s + time.perf_counter() - self._t0

    def _note(self) -> None:
        if self.writes:
            write_json(self.dir / RUN_FILE, {"spent_s": self.spent_s()})

    def job(self, name: str) -> "JobState":
        """The state of the job called ``name`` (unique within the call)."""
        return JobState(self, self.dir / f"{name}.pt")

    def finished(self) -> None:
        """The call wrote its results: nothing is left to resume."""
        if self.writes:
            shutil.rmtree(self.dir, ignore_errors=True)


class JobState:
    """One job's state file: ``save`` after each epoch, ``load`` when the job is built."""

    def __init__(self, run: RunStates, path: Path) -> None:
        self.run, self.path = run, path
        self.built_from: dict[str, Any] | None = None

    def load(self, built_from: dict[str, Any]) -> dict[str, Any] | None:
        """The saved state of a job built from ``built_from`` (JSON-able), or None where
        there is none to go on from; ValueError where it is another job's."""
        self.built_from = json.loads(json.dumps(built_from, default=str))
        if not (self.run.resume and self.path.is_file()):
            return None
        state = torch.load(self.path, map_location="cpu", weights_only=False)
        if state.get("built_from") != self.built_from:
            was = state.get("built_from") or {}
            diff = sorted(k for k in set(was) | set(self.built_from)
                          if was.get(k) != self.built_from.get(k))
            raise ValueError(f"--resume: {self.path} is the state of another run (it differs "
                             f"in {', '.join(diff)}); run without --resume to start afresh")
        return state

    def save(self, state: dict[str, Any]) -> None:
        """Write ``state`` atomically (an interruption leaves the previous one)."""
        with atomic_path(self.path) as tmp:
            torch.save(dict(state, built_from=self.built_from), tmp)
        self.run._note()
