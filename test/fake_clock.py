"""The one fake clock of the tests: a monotonic clock that moves only when told to.

Code under test takes ``clock`` (a callable returning seconds) and, where it waits,
``sleep``; a test sets or advances ``t`` and reads back the sleeps that were asked for.
"""

from __future__ import annotations


class FakeClock:
    """Callable like ``time.monotonic``; ``sleep(s)`` records ``s`` and advances the time."""

    def __init__(self, t: float = 0.0) -> None:
        self.t = float(t)
        self.sleeps: list[float] = []

    def __call__(self) -> float:
        return self.t

    def sleep(self, s: float) -> None:
        self.sleeps.append(s)
        self.t += s
