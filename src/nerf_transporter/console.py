"""What the commands share on the terminal: `--help` formatting, progress that reads in a log."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from typing import Any

from tqdm.auto import tqdm


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """`--help` shows each option's default, except where there is none (None, False flags):
    those options say in their own help what happens without them."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        if action.default in (None, False) or action.default is argparse.SUPPRESS:
            return action.help
        return super()._get_help_string(action)


class LineBar:
    """The part of tqdm's interface the commands use (update, set_postfix, close), written as a
    plain line on stderr at most every `every_s` seconds (of `clock`) and when the count reaches
    its total."""

    def __init__(
        self,
        total: int,
        desc: str,
        unit: str = "episode",
        initial: int = 0,
        every_s: float = 30.0,
        clock: Callable[[], float] = time.perf_counter,
    ) -> None:
        self.total, self.desc, self.unit, self.n, self.every_s = total, desc, unit, initial, every_s
        self.postfix: dict[str, Any] = {}
        self._clock = clock
        self._start_n, self._start = initial, clock()
        self._last = self._start

    def set_postfix(self, **values: Any) -> None:
        self.postfix = values

    def update(self, n: int = 1) -> None:
        self.n += n
        now = self._clock()
        if now - self._last >= self.every_s or self.n >= self.total:
            self._last = now
            print(self.line(now), file=sys.stderr, flush=True)

    def line(self, now: float) -> str:
        done = self.n - self._start_n
        values = "".join(f"  {name} {value}" for name, value in self.postfix.items())
        pace = f"  {(now - self._start) / done:.1f} s/{self.unit}" if done else ""
        return f"{self.desc}: {self.n}/{self.total} {self.unit}s{values}{pace}"

    def close(self) -> None:
        """Nothing to clear: every line written stays."""

    def __enter__(self) -> LineBar:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def progress_bar(
    total: int, desc: str, unit: str = "episode", enabled: bool = True, **tqdm_options: Any
) -> tqdm | LineBar:
    """A tqdm bar where stderr is a terminal; where it is not (a log file, which a bar would fill
    with carriage-return frames) a `LineBar`; nothing shown when not `enabled`."""
    if not enabled or sys.stderr.isatty():
        return tqdm(total=total, desc=desc, unit=unit, disable=not enabled, **tqdm_options)
    return LineBar(total, desc, unit, initial=tqdm_options.get("initial", 0))
