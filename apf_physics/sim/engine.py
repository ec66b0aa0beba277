"""The episode stepper: the one place where robots advance and episodes end.

A :class:`Stepper` runs a batch of episodes ("slots"), each of one or several robots in a
world: the single environment (a batch of one), the vector environment, ``eval``'s rollouts
and formations all call it. Each control step it takes a velocity command per robot, moves
every robot of the running slots through one :class:`~apf_physics.sim.physics.Physics` call,
and decides how each episode stands, with one definition for all callers (Model §2,
episode rules):

- **reached at the start**: :meth:`Stepper.start` ends at once, as reached after 0 steps, an
  episode whose leader starts within the goal tolerance of a target; the next
  :meth:`Stepper.step` reports it as ended (and reached) without moving it;
- **collision**: any robot of the slot touched an obstacle, the map's edge or another robot
  during the step (every robot involved is flagged in :attr:`StepReport.contacts`);
- **reached**: otherwise, the slot's leader (robot 0) ends the step within the goal
  tolerance of a target;
- **trapped**: otherwise, the caller's planner gave up (``gave_up``), or the
  :class:`TrapDetector` given to the stepper sees the leader stuck;
- **timeout**: otherwise, the episode has run ``max_steps`` control steps.

Which callers use which rules: every caller gets the first three. ``eval``'s rollouts
(:mod:`apf_physics.experiments.rollout`) give the stepper their planner's trap detector (its rule and
window), its give-up signal, and a step limit; the environments have a step limit
(Gymnasium's ``TimeLimit`` for the single ones) and a trap detector only when asked for
(their ``trap`` option, default None: no trap rule, as in training). With the same detector
and limit, an environment driven by a planner's moves and ``eval`` running that planner end
the same episode the same way, at the same step.

An ended slot's robots stay where the episode ended until :meth:`Stepper.start` begins the
slot's next episode.

**Robot kinds.** Holonomic robots (the thesis's) are commanded a velocity. Unicycle robots
(``unicycle=`` limits, :mod:`apf_physics.world.kinematics`) have a heading, kept here with the
last command; they are commanded ``(v, ω)``, which the stepper bounds by the limits and turns
into a velocity per physics substep, so that the physics sweeps each robot's disc along its
exact arc (the same substeps keep it from tunnelling). The episode rules are the same.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import Literal, Sequence

import numpy as np

from apf_physics.common.compiled import kernel
from apf_physics.world.kinematics import UnicycleLimits, substep_velocities, wrap_angle
from apf_physics.sim.physics import MAX_SPEED, ContactLog, Physics
from apf_physics.world.core import Moment, World

TrapRule = Literal["descent", "oscillation"]


class Outcome(IntEnum):
    """How an episode stands."""

    RUNNING = 0
    REACHED = 1
    COLLISION = 2
    TRAPPED = 3
    TIMEOUT = 4

    @property
    def label(self) -> str:
        """``"running"``, ``"reached"``, ``"collision"``, ``"trapped"`` or ``"timeout"``."""
        return self.name.lower()


# The same as plain ints, for the arrays of the step loop (an IntEnum member costs a lookup each use).
RUNNING, REACHED, COLLISION, TRAPPED, TIMEOUT = (int(o) for o in Outcome)


@dataclass(frozen=True)
class TrapDetector:
    """Decides when a robot is stuck, from its recent history.

    Attributes:
        rule: ``"oscillation"``: trapped when every position of the last ``window`` steps lies
            within ``radius`` of their mean. ``"descent"`` (gradient descent): also when the
            lowest potential of the window is not at least ``min_drop`` below the lowest
            potential before it.
        window: Control steps looked back over.
        radius: See ``rule`` [units].
        min_drop: See ``rule``.
    """

    rule: TrapRule = "oscillation"
    window: int = 10
    radius: float = 1.5
    min_drop: float = 1e-3


class TrapWatch:
    """Ring buffers of the last ``window`` leader positions (and potentials) of every slot."""

    def __init__(self, detector: TrapDetector, num_slots: int):
        self.detector = detector
        w = detector.window
        self.positions = np.zeros((num_slots, w, 2))
        self.potentials = np.zeros((num_slots, w))
        self.earlier_min = np.full(num_slots, np.inf)   # lowest potential before the window
        self.length = np.zeros(num_slots, np.intp)      # entries recorded in this episode

    def reset(self, slots: np.ndarray, positions: np.ndarray, potentials: np.ndarray) -> None:
        self.length[slots] = 0
        self.earlier_min[slots] = np.inf
        self.record(slots, positions, potentials)

    def record(self, slots: np.ndarray, positions: np.ndarray, potentials: np.ndarray) -> np.ndarray:
        """Add one entry per slot of ``slots``; returns which of them are trapped now."""
        d = self.detector
        w = d.window
        at = self.length[slots] % w
        full = self.length[slots] >= w
        leaving = self.potentials[slots, at]
        self.earlier_min[slots] = np.where(full, np.minimum(self.earlier_min[slots], leaving), self.earlier_min[slots])
        self.positions[slots, at] = positions
        self.potentials[slots, at] = potentials
        self.length[slots] += 1
        judged = self.length[slots] > w
        recent = self.positions[slots]
        spread = np.max(np.hypot(*(recent - recent.mean(axis=1, keepdims=True)).transpose(2, 0, 1)), axis=1)
        trapped = judged & (spread < d.radius)
        if d.rule == "descent":
            trapped |= judged & (self.potentials[slots].min(axis=1) > self.earlier_min[slots] - d.min_drop)
        return trapped


@dataclass
class StepReport:
    """What one control step did.

    Attributes:
        positions: (S, m, 2) every robot's position after the step (frozen for ended slots).
        contacts: The physics' contact log, per robot (global index ``slot * m + r``).
        moved: (S,) bool: the slots that were running at the start of the step.
        collided: (S,) bool: a robot of a moved slot touched something.
        reached: (S,) bool: the leader of a moved slot reached a target (and nothing collided).
        ended: (S,) bool: episodes that ended at this step.
        distance: (S,) leader's distance to the nearest target of its world.
        everyone: Every slot was running (``moved`` is all true).
    """

    positions: np.ndarray
    contacts: ContactLog
    moved: np.ndarray
    collided: np.ndarray
    reached: np.ndarray
    ended: np.ndarray
    distance: np.ndarray
    everyone: bool = True


class Stepper:
    """Episodes of robots in slots, advanced together through one physics.

    Args:
        worlds: The worlds episodes may use; slot ``s`` is in ``worlds[world_of[s]]``.
        num_slots: Episodes run at once.
        robots_per_slot: Robots per episode; robot 0 is the leader.
        max_steps: An episode that has run this many control steps ends as ``timeout``
            (None: never).
        trap: Trap detection for the leaders (None: none).
        crowds: Slots with the same crowd number share the map and their robots meet: several
            formations in one world, a slot each (default: every slot on its own). Start a
            crowd's slots together.
        unicycle: The robots are unicycles with these limits (None: holonomic); see the module
            docstring.
        arrival: ``"end"``: a leader that reaches a target ends its episode (the rules above);
            ``"continue"``: it does not (a fleet's robot stays in play on its goal, and may be given
            another one with :meth:`set_targets`): :attr:`StepReport.reached` says who stands within
            the goal tolerance of a target after the step, and episodes end only by a collision,
            the trap rule, the step limit or :meth:`finish`.
    """

    def __init__(self, worlds: Sequence[World], num_slots: int, robots_per_slot: int = 1,
                 max_steps: int | None = None, trap: TrapDetector | None = None,
                 crowds: Sequence[int] | None = None, unicycle: UnicycleLimits | None = None,
                 arrival: Literal["end", "continue"] = "end"):
        if arrival not in ("end", "continue"):
            raise ValueError(f"arrival must be 'end' or 'continue', got {arrival!r}")
        self.ends_at_target = arrival == "end"
        self.worlds = list(worlds)
        self.num_slots = int(num_slots)
        self.robots_per_slot = int(robots_per_slot)
        self.max_steps = max_steps
        self.unicycle = unicycle
        top = MAX_SPEED if unicycle is None else max(MAX_SPEED, unicycle.top_speed)
        self.physics = Physics([self.worlds[0]] * self.num_slots, self.robots_per_slot, max_speed=top,
                               other_worlds=self.worlds, crowds=crowds)
        self.headings = np.zeros((self.num_slots, self.robots_per_slot))
        """(S, m) each robot's heading θ [rad] (unicycles; zeros for holonomic robots)."""
        self.drive = np.zeros((self.num_slots, self.robots_per_slot, 2))
        """(S, m, 2) each unicycle's last command ``(v, ω)``, after the limits (what its acceleration is bounded against)."""
        self.world_of = np.zeros(self.num_slots, np.intp)
        self.positions = np.zeros((self.num_slots, self.robots_per_slot, 2))
        self.steps = np.zeros(self.num_slots, np.intp)
        self.outcome = np.full(self.num_slots, TIMEOUT, np.int8)   # nothing runs before start()
        n_targets = max(len(w.targets) for w in self.worlds)
        self._targets = np.full((len(self.worlds), n_targets, 2), np.inf)
        for i, w in enumerate(self.worlds):
            self._targets[i, :len(w.targets)] = w.targets
        self._tolerance = np.array([w.goal_tolerance for w in self.worlds])
        self._slot_targets = self._targets[self.world_of]       # (S, T, 2): each slot's world's targets
        self._slot_tolerance = self._tolerance[self.world_of]
        self.trap = trap
        self._watch = TrapWatch(trap, self.num_slots) if trap is not None else None
        self._nobody = np.zeros(self.num_slots, bool)
        self._unreported = np.zeros(self.num_slots, bool)   # ended at their start, not yet in a report
        self._any_unreported = False
        self._moving = any(w.moving for w in self.worlds)
        self.last_distance = np.full(self.num_slots, np.inf)
        """Each leader's distance to its nearest target, after the last start or step."""

    @property
    def running(self) -> np.ndarray:
        """(S,) bool: slots whose episode is still going."""
        return self.outcome == RUNNING

    def world(self, slot: int) -> World:
        return self.worlds[self.world_of[slot]]

    def set_targets(self, slots: np.ndarray, targets: np.ndarray) -> None:
        """Give the slots of ``slots`` targets of their own, ``targets`` (k, 2), instead of their world's
        (a fleet: one map, a goal per robot). A slot put in another world by :meth:`start` takes that
        world's targets again."""
        slots = np.asarray(slots, np.intp).reshape(-1)
        self._slot_targets[slots] = np.inf
        self._slot_targets[slots, 0] = np.asarray(targets, float).reshape(-1, 2)

    def moment(self, slot: int) -> Moment:
        """The world of ``slot`` at its episode's step (where its moving obstacles are): what a
        planner steering the slot's robots is given for this control step."""
        return self.world(slot).at(int(self.steps[slot]))

    def distance(self) -> np.ndarray:
        """(S,) each leader's distance to the nearest target of its world."""
        return _nearest(np.ascontiguousarray(self.positions[:, 0]), self._slot_targets)

    def poses(self) -> np.ndarray:
        """(S, m, 3) every robot's ``(x, y, θ)``."""
        return np.concatenate([self.positions, self.headings[..., None]], axis=2)

    def states(self) -> np.ndarray:
        """(S, m, 5) every robot's unicycle state ``(x, y, θ, v, ω)`` (:mod:`apf_physics.world.kinematics`)."""
        return np.concatenate([self.positions, self.headings[..., None], self.drive], axis=2)

    def _leader_potential(self, slots: np.ndarray) -> np.ndarray:
        """U at each leader of ``slots``, at its episode's step (for the ``"descent"`` trap rule)."""
        if self.trap is None or self.trap.rule != "descent":
            return np.zeros(len(slots))
        out = np.empty(len(slots))
        keys = self.world_of[slots] * (self.steps.max(initial=0) + 1) + self.steps[slots]
        for key in np.unique(keys).tolist():
            mine = keys == key
            out[mine] = self.moment(int(slots[mine][0])).potential(self.positions[slots[mine], 0])
        return out

    def start(self, slots: np.ndarray, positions: np.ndarray, world_ids: np.ndarray | None = None,
              present: np.ndarray | None = None, headings: np.ndarray | None = None) -> None:
        """Begin episodes in ``slots``: robots at ``positions`` (k, m, 2), in ``worlds[world_ids]``
        (default: each slot's world as it was; the first world before any).

        An episode whose leader starts within the goal tolerance of a target of its world ends
        at once, reached after 0 steps; the next :meth:`step` reports it (``ended`` and
        ``reached``, not ``moved``).

        ``present``: (k, m) bool, the robots that exist (a formation smaller than the slot has
        absent ones, which never move or touch anything); default all.

        ``headings``: (k, m) unicycles' initial headings [rad]; default: every robot of a slot
        faces the target nearest its leader. Unicycles start at rest.
        """
        slots = np.asarray(slots, np.intp).reshape(-1)
        m = self.robots_per_slot
        positions = np.asarray(positions, float).reshape(len(slots), m, 2)
        robots = (slots[:, None] * m + np.arange(m)).ravel() if m > 1 else slots
        self.physics.present[robots] = True if present is None else np.asarray(present, bool).reshape(-1)
        if world_ids is not None and len(self.worlds) > 1:
            changed = slots[self.world_of[slots] != world_ids]   # slots changing worlds
            if len(changed):
                self.world_of[slots] = world_ids
                for s in changed.tolist():
                    self.physics.set_world(s, self.worlds[self.world_of[s]])
                self._slot_targets[changed] = self._targets[self.world_of[changed]]
                self._slot_tolerance[changed] = self._tolerance[self.world_of[changed]]
        self.steps[slots] = 0
        if self._moving:   # placed among the moving obstacles where they are at step 0
            self.physics.set_time(self.steps)
        self.physics.place(robots, positions.reshape(-1, 2))
        self.positions = self.positions.copy()   # never change an array a report handed out
        self.positions[slots] = positions
        self.outcome[slots] = RUNNING
        if self.unicycle is not None:
            self._face(slots, positions, headings)
        self.last_distance = self.last_distance.copy()
        self.last_distance[slots] = distance = _nearest(np.ascontiguousarray(positions[:, 0]), self._slot_targets[slots])
        if self._watch is not None:
            self._watch.reset(slots, positions[:, 0], self._leader_potential(slots))
        arrived = (distance <= self._slot_tolerance[slots]) & self.ends_at_target
        self.outcome[slots[arrived]] = REACHED
        self._unreported[slots] = arrived
        self._any_unreported = bool(np.count_nonzero(self._unreported))

    def _face(self, slots: np.ndarray, positions: np.ndarray, headings: np.ndarray | None) -> None:
        """Unicycles of ``slots`` at rest, headed as given or toward the target nearest each leader."""
        self.headings = self.headings.copy()
        if headings is None:
            d = self._slot_targets[slots] - positions[:, :1, :]                       # (k, T, 2)
            nearest = np.argmin(np.hypot(d[..., 0], d[..., 1]), axis=1)
            toward = d[np.arange(len(slots)), nearest]
            headings = np.broadcast_to(np.arctan2(toward[:, 1], toward[:, 0])[:, None], (len(slots), self.robots_per_slot))
        self.headings[slots] = wrap_angle(np.asarray(headings, float).reshape(len(slots), self.robots_per_slot))
        self.drive[slots] = 0.0

    def _drive(self, commands: np.ndarray, moved: np.ndarray) -> np.ndarray:
        """Unicycles' ``(v, ω)`` commands (S, m, 2) as (N, substeps, 2) velocities along their arcs;
        the headings and last commands of the robots of ``moved`` slots advance."""
        limits = self.unicycle
        commands = np.asarray(commands, float).reshape(self.num_slots, self.robots_per_slot, 2)
        v, omega = limits.clamp(commands[..., 0], commands[..., 1], self.drive[..., 0], self.drive[..., 1])
        state = self.states().reshape(-1, 5)
        velocities = substep_velocities(state, v.ravel(), omega.ravel(), self.physics.substeps,
                                        self.physics.control_dt)
        go = moved[:, None] & self.physics.present.reshape(self.num_slots, -1)
        self.headings = np.where(go, wrap_angle(self.headings + omega * self.physics.control_dt), self.headings)
        self.drive = np.where(go[..., None], np.stack([v, omega], axis=-1), self.drive)
        return velocities

    def finish(self, slots: np.ndarray, outcome: Outcome) -> None:
        """End the running episodes among ``slots`` with ``outcome`` (e.g. a planner that gave up)."""
        slots = np.asarray(slots, np.intp).reshape(-1)
        self.outcome[slots[self.outcome[slots] == RUNNING]] = int(outcome)

    def step(self, commands: np.ndarray, gave_up: np.ndarray | None = None) -> StepReport:
        """Advance every running slot by one control step.

        Args:
            commands: (S, m, 2) velocity commands (units per control step), or for unicycles
                ``(v, ω)`` [units/step, rad/step], bounded by the limits; those of slots that
                are not running are ignored.
            gave_up: (S,) bool: slots whose planner knows it is trapped; they end as ``trapped``
                before moving.
        """
        if gave_up is not None and np.count_nonzero(gave_up):
            self.finish(np.flatnonzero(gave_up), Outcome.TRAPPED)
        moved, everyone = _running(self.outcome)
        if self.unicycle is not None:
            commands = self._drive(commands, moved)
        else:
            commands = np.asarray(commands, float).reshape(-1, 2)
        if self._moving:
            self.physics.set_time(self.steps)
        contacts = self.physics.step(commands, None if everyone else np.repeat(moved, self.robots_per_slot))
        after = self.physics.positions.reshape(self.positions.shape)
        # a new array every step: the report can hand it out
        self.positions = after if everyone else np.where(moved[:, None, None], after, self.positions)
        touched = contacts.any.reshape(self.num_slots, -1).any(axis=1) if contacts.touched else self._nobody
        watch = self._watch is not None
        outcome = self.outcome.copy()
        distance, collided, reached, ended = _episode_rules(
            self.positions, self._slot_targets, self._slot_tolerance, moved, touched, self.steps,
            -1 if self.max_steps is None or watch else int(self.max_steps), outcome, self.ends_at_target)
        if watch:   # the trap rule judges the slots still running, before the step limit does
            judge = np.flatnonzero(moved & (outcome == RUNNING))
            trapped = self._watch.record(judge, self.positions[judge, 0], self._leader_potential(judge))
            outcome[judge[trapped]] = TRAPPED
            if self.max_steps is not None:
                outcome[moved & (outcome == RUNNING) & (self.steps >= self.max_steps)] = TIMEOUT
            ended = moved & (outcome != RUNNING)
        self.outcome = outcome
        if self._any_unreported:   # episodes that ended at their start: reported once, by this step
            ended = ended | self._unreported
            reached = reached | self._unreported
            self._unreported[:] = False
            self._any_unreported = False
        self.last_distance = distance
        return StepReport(self.positions, contacts, moved, collided, reached, ended, distance, everyone)


@kernel
def _nearest(leaders, targets):
    """(k,) the distance of each of ``leaders`` (k, 2) to the nearest of its ``targets`` (k, T, 2)
    (absent targets are at infinity)."""
    out = np.empty(leaders.shape[0])
    for s in range(leaders.shape[0]):
        best = np.inf
        for t in range(targets.shape[1]):
            d = np.hypot(leaders[s, 0] - targets[s, t, 0], leaders[s, 1] - targets[s, t, 1])
            if d < best:
                best = d
        out[s] = best
    return out


@kernel
def _running(outcome):
    """``(moved, everyone)``: (S,) the slots whose episode runs, and whether all do."""
    moved = np.empty(outcome.shape[0], np.bool_)
    everyone = True
    for s in range(outcome.shape[0]):
        moved[s] = outcome[s] == RUNNING
        everyone = everyone and moved[s]
    return moved, everyone


@kernel
def _episode_rules(positions, targets, tolerance, moved, touched, steps, max_steps, outcome, ends_at_target):
    """The episode rules of one step, for every slot (see the module docstring): the step count of
    each slot that moved advanced (in ``steps``), each leader's (``positions[:, 0]``) distance to
    its nearest target, and for the slots that moved, whether a robot collided, whether the leader
    reached a target (and nothing collided), and the outcome (collision, reached when
    ``ends_at_target``, or the step limit when ``max_steps`` ≥ 0), written into ``outcome``.

    Returns:
        ``(distance, collided, reached, ended)``, each (S,).
    """
    n = positions.shape[0]
    distance = _nearest(positions[:, 0], targets)
    collided = np.zeros(n, np.bool_)
    reached = np.zeros(n, np.bool_)
    ended = np.zeros(n, np.bool_)
    for s in range(n):
        if not moved[s]:
            continue
        steps[s] += 1
        collided[s] = touched[s]
        reached[s] = distance[s] <= tolerance[s] and not touched[s]
        if collided[s]:
            outcome[s] = COLLISION
        elif reached[s] and ends_at_target:
            outcome[s] = REACHED
        elif 0 <= max_steps <= steps[s]:
            outcome[s] = TIMEOUT
        ended[s] = outcome[s] != RUNNING
    return distance, collided, reached, ended
