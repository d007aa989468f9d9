"""Rank 0's progress during a run (docs/running.md): a tqdm bar on a terminal, plain log lines otherwise.

The time left printed while a run goes (``ETA``) is the mean time per finished row so far times the rows left,

    eta = elapsed / n * (total - n)        [s]   (n: rows finished by this run, n > 0; unknown (NaN) for n = 0)

-- the run's own rate, with no cost model. The cost left in a store between runs, calibrated per method on the
measured rows, is gapsweep.sweep.costleft (``gapsweep status``).
"""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Callable

from gapsweep.sweep.schema import STATUS, TaskResult

__all__ = ["Progress", "eta_s"]

log = logging.getLogger("gapsweep.runner")


def eta_s(elapsed: float, n: int, total: int) -> float:
    """Seconds left when ``n`` of ``total`` rows finished in ``elapsed`` seconds, at the run's mean rate so far
    (module docstring); NaN before the first row."""
    return elapsed / n * (total - n) if n else float("nan")


class Progress:
    """Rank 0's progress: a tqdm bar on a terminal, plain log lines (every ``every`` s) otherwise; ``mode``:
    auto | bar | log | none. ``clock``: the monotonic clock [s] (a stand-in in tests)."""

    def __init__(self, total: int, mode: str = "auto", every: float = 10.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.total, self.count = total, dict.fromkeys(STATUS, 0)
        self.clock = clock
        self.t0 = self.last = clock()
        self.every = every
        tty = sys.stderr.isatty()
        self.mode = ("bar" if tty else "log") if mode == "auto" else mode
        self.bar = None
        if self.mode == "bar" and total:
            try:
                from tqdm import tqdm
            except ImportError:  # the `progress` extra is not installed: log lines instead of a bar
                self.mode = "log"
            else:
                self.bar = tqdm(total=total, unit="task", dynamic_ncols=True, file=sys.stderr)

    def update(self, res: TaskResult, i: int | None = None) -> None:
        """Count one finished row (its status) and show it: the bar moves, or a log line every ``every`` s.
        ``i``: the row's task index, by which a launch's joint farm finds its job (gapsweep.sweep.launch)."""
        self.count[res.status] += 1
        if self.bar is not None:
            self.bar.update(1)
            self.bar.set_postfix(failed=self.count["failed"], not_conv=self.count["not_converged"], refresh=False)
        elif self.mode == "log":
            t = self.clock()
            if t - self.last >= self.every:
                self.last = t
                log.info(self.line())

    def line(self) -> str:
        """The progress as one line: rows finished by status, remaining, elapsed time and ETA (:func:`eta_s`)."""
        n = sum(self.count.values())
        el = self.clock() - self.t0
        eta = eta_s(el, n, self.total)
        return (f"{n}/{self.total} finished ({self.count['done']} done, {self.count['failed']} failed, "
                f"{self.count['not_converged']} not converged), {self.total - n} remaining, "
                f"elapsed {el:.1f} s, ETA {eta:.1f} s")

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
        if self.mode != "none":
            log.info(self.line())
