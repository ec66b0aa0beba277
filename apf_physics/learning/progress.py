"""What a training run shows while it runs: a bar on a terminal, plain lines anywhere else.

On a terminal, a tqdm bar on stderr measures the budget that stops the run (steps, searches,
the stages' searches, or seconds when a time limit is the only one), says the targets if there
are any (of the validation starts, and of the world starts), and shows ε and the latest
evaluation (on the validation starts, and on the world starts) in its postfix. When stderr is not a terminal (``nohup``, CI, a notebook cell, a pipe)
there is no bar and no carriage return: one plain line per row of ``train.csv``, as
Stable-Baselines3's logger prints, with the step, the latest evaluation, the loss and the
elapsed time. Both name the figures as ``train.csv`` does.
"""

from __future__ import annotations

import sys
from typing import Any, Optional, Sequence, TextIO

from tqdm import tqdm

from apf_physics.learning.config import TrainConfig
from apf_physics.learning.learner import Counters
from apf_physics.learning.phases import Phase


class Progress:
    """A run's progress display (``stream``: default stderr; a bar only if it is a terminal)."""

    def __init__(self, config: TrainConfig, phases: Sequence[Phase], c: Counters, stream: Optional[TextIO] = None):
        self.stream = sys.stderr if stream is None else stream
        self.budgets = [p.episodes for p in phases]
        s = config.schedule
        if s.total_steps is not None:
            self.measure, total, unit = "steps", s.total_steps, "step"
        elif s.total_episodes is not None:
            self.measure, total, unit = "episodes", s.total_episodes, "search"
        elif s.time_limit is not None:
            self.measure, total, unit = "seconds", s.time_limit, "s"
        elif all(b is not None for b in self.budgets):
            self.measure, total, unit = "stage_episodes", sum(self.budgets), "search"
        else:
            self.measure, total, unit = "steps", None, "step"
        self.total, self.unit = total, unit
        self.multi = len(phases) > 1
        # the world starts are shown beside the validation starts when they are not the same starts
        self.world_starts = [None if p.world_starts is None or p.world_starts is p.validation else p.world_starts.starts
                             for p in phases]
        self._desc = "" if s.target_success is None else f"until {s.target_success:.0%} of the validation starts"
        if self._desc and s.target_world_starts is not None and config.evaluation.eval_random_starts \
                and any(self.world_starts):
            self._desc += f" and {s.target_world_starts:.0%} of the world starts"
        self.bar = None
        if self.stream.isatty():
            self.bar = tqdm(total=total, initial=self._value(c), unit=unit, desc=self._desc or None,
                            dynamic_ncols=True, smoothing=0.05, file=self.stream)

    def _value(self, c: Counters) -> float:
        if self.measure == "steps":
            return c.global_step
        if self.measure == "episodes":
            return c.episodes
        if self.measure == "seconds":
            return round(c.wall_time, 1)
        return sum(b for b in self.budgets[:c.phase]) + c.phase_episodes

    def update(self, c: Counters, phase: Phase, epsilon: Any, latest: Optional[dict]) -> None:
        """After every step: move the bar (a terminal only)."""
        if self.bar is None:
            return
        if self.multi:
            desc = f"{phase.name}" + (f", {self._desc}" if self._desc else "")
            if desc != self.bar.desc:
                self.bar.set_description_str(desc, refresh=False)
        eps = f"ε {epsilon:.2f}, " if isinstance(epsilon, float) else ""
        self.bar.set_postfix_str(eps + self.figures(latest, c.phase), refresh=False)
        value = self._value(c) if self.bar.total is None else min(self._value(c), self.bar.total)
        self.bar.update(value - self.bar.n)

    def figures(self, summary: Optional[dict], phase: int) -> str:
        """``validation starts 97.3%, world starts 40/40`` (``validation starts -`` before any evaluation)."""
        if summary is None:
            return "validation starts -"
        text = f"validation starts {summary['success']:.1%}"
        world = summary.get("world_starts_success")
        n = self.world_starts[min(phase, len(self.world_starts) - 1)]
        if world is not None and n:
            text += f", world starts {round(world * n)}/{n}"
        return text

    def line(self, row: dict[str, Any], latest: Optional[dict], phase: int = 0) -> None:
        """After every row of ``train.csv``: one plain line, when there is no bar."""
        if self.bar is not None:
            return
        of = "" if self.total is None or self.measure != "steps" else f"/{self.total:,}"
        parts = [f"step {row['global_step']:,}{of}", f"phase {row['phase']}", f"episodes {row['episodes']:,}"]
        if row["validation_success"] != "":
            parts.append(self.figures(latest, phase))
        elif latest is not None:
            parts.append("last evaluation: " + self.figures(latest, phase))
        if row["epsilon"] != "":
            parts.append(f"ε {row['epsilon']:.3f}")
        if row["loss"] != "":
            parts.append(f"loss {row['loss']:.4g}")
        parts.append(f"{row['wall_time']:.0f} s")
        print("train: " + ", ".join(parts), file=self.stream, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
