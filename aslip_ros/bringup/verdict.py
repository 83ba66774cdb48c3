"""The verdict every check ends with: OK, or FAIL with the reasons, as one line and an exit
code (0 or 1, the ``aslip`` command's rule)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import List

EXIT_OK, EXIT_FAIL = 0, 1


@dataclass
class Verdict:
    """Reasons to fail, collected while a check runs, and notes that do not fail it."""

    problems: List[str] = field(default_factory=list)
    notes: List[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """True when nothing failed."""
        return not self.problems

    def fail(self, reason: str) -> 'Verdict':
        """Record a reason to fail; returns self."""
        self.problems.append(reason)
        return self

    def line(self) -> str:
        """``verdict: OK`` or ``verdict: FAIL: reason; reason``."""
        return 'verdict: OK' if self.ok else 'verdict: FAIL: ' + '; '.join(self.problems)

    @property
    def exit_code(self) -> int:
        """0 when OK, 1 on FAIL."""
        return EXIT_OK if self.ok else EXIT_FAIL

    def report(self, out) -> int:
        """Print the notes and the verdict line to ``out``; return the exit code."""
        for note in self.notes:
            print(f'note: {note}', file=out)
        print(self.line(), file=out, flush=True)
        return self.exit_code
