"""The navigation task for a batch of episodes: what every environment of the package steps.

One step: actions → the stepper's commands (unit moves, Model Table 1; or a continuous
velocity, or a unicycle's ``(v, ω)``: :class:`~apf_physics.envs.options.RobotOptions`) →
followers' moves (formations) → one :class:`~apf_physics.sim.engine.Stepper` step for the whole
batch → observations (one call of the task's observation kind, whichever it is:
:mod:`apf_physics.sensing.kinds`) and the reward's named terms. ``Navigate-v0``
is a batch of one, :class:`~apf_physics.envs.vector.NavigateVectorEnv` a batch of N, and
``Formation-v0`` a batch of one formation.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence, Union

import numpy as np
from gymnasium import spaces

from apf_physics.control.fleet import STAY, GoalStream, Lattice, fleet_moves, place_fleet
from apf_physics.control.shield import ACTIONS
from apf_physics.sim.engine import TIMEOUT, TRAPPED, Stepper, TrapDetector
from apf_physics.envs.options import RobotOptions
from apf_physics.errors import UserError
from apf_physics.envs.reward import RewardWeights, rewards
from apf_physics.control.formation import Formations, FormationTeam
from apf_physics.sensing.kinds import Robots, make_observation
from apf_physics.sensing.lidar import LidarConfig
from apf_physics.sensing.observation import Observer, ObserverConfig
from apf_physics.control.tracking import UnicycleFollowers, leader_caps, team_drive
from apf_physics.world.core import FormationSpec, World




@dataclass
class TaskStep:
    """One step of the batch (arrays over slots). (Not a frozen dataclass: one is made every step,
    and a frozen one's ``__init__`` costs several times a plain one's.)"""

    observation: np.ndarray | dict  # (N, C, k, k) float32 windows, (N, K + 5) ranges, or a dict of both
    reward: np.ndarray         # (N,) float64, 0 where nothing moved
    terminated: np.ndarray     # (N,) bool: reached or collided
    truncated: np.ndarray      # (N,) bool: the step limit
    terms: np.ndarray          # (6, N) the reward's terms, rows in envs.reward.TERMS order
    reached: np.ndarray        # (N,) bool
    collided: np.ndarray       # (N,) bool
    moved: np.ndarray          # (N,) bool: slots that were running
    robot_contact: np.ndarray  # (N,) bool: two robots of the slot touched
    trapped: np.ndarray        # (N,) bool: the trap detector ended the episode (truncated)


TrapOption = Union[None, str, TrapDetector]
"""The environments' ``trap`` option (:func:`trap_detector`)."""
TRAP_RULES = ("oscillation", "descent")


def trap_detector(trap: TrapOption) -> TrapDetector | None:
    """The environments' ``trap`` option as the stepper's detector.

    None (the default): no trap rule, episodes end only by reaching, colliding or the step
    limit (as in training). ``"oscillation"`` or ``"descent"``: that rule of
    :class:`~apf_physics.sim.engine.TrapDetector` with its defaults (a window of 10 steps, radius
    1.5), the detector ``eval`` gives a planner with that rule and no window of its own. A
    :class:`~apf_physics.sim.engine.TrapDetector`: as it is (e.g. ``TrapDetector(window=40)``,
    a DQN planner's with a visit memory).

    Raises:
        UserError: Anything else.
    """
    if trap is None or isinstance(trap, TrapDetector):
        return trap
    if isinstance(trap, str) and trap in TRAP_RULES:
        return TrapDetector(trap)
    raise UserError(f"trap must be None, one of {', '.join(TRAP_RULES)} or a TrapDetector, got {trap!r}")


def _zeros(space: spaces.Space, num: int) -> np.ndarray | dict:
    """``num`` rows of zeros of a ``Box`` (or of each ``Box`` of a ``Dict``)."""
    if isinstance(space, spaces.Dict):
        return {name: _zeros(part, num) for name, part in space.spaces.items()}
    return np.zeros((num, *space.shape), space.dtype)


def _with_rows(observation: np.ndarray | dict, slots: np.ndarray, rows: np.ndarray | dict) -> np.ndarray | dict:
    """A copy of ``observation`` with ``rows`` in ``slots`` (an array handed out is never changed)."""
    if isinstance(observation, dict):
        return {name: _with_rows(part, slots, rows[name]) for name, part in observation.items()}
    out = observation.copy()
    out[slots] = rows
    return out


def _ends(ended: np.ndarray, outcome: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(terminated, truncated, trapped)`` of the episodes that ``ended``, from their outcome:
    reached or collided terminate; the step limit and the trap detector truncate."""
    if not np.count_nonzero(ended):   # (a quarter of ndarray.any's cost on a few flags: every step asks)
        return ended, ended, ended
    trapped = ended & (outcome == TRAPPED)
    truncated = trapped | (ended & (outcome == TIMEOUT))
    return ended & ~truncated, truncated, trapped


class NavigationTask:
    """N episodes of the navigation task, slot n in world ``worlds[world_of[n]]``.

    Args:
        worlds: The worlds episodes may use.
        num: Batch size.
        observer: How observations are built.
        weights: Reward weights.
        formation: Followers behind each leader (None: robots alone).
        max_steps: Truncate episodes after this many steps (None: never; the single
            environments leave it to Gymnasium's ``TimeLimit``).
        trap: Truncate episodes whose leader the trap detector finds stuck (:func:`trap_detector`;
            default None: no trap rule).
        robot: The robot's kind, its actions and what it sees (default: the thesis's).

    The episode rules are the stepper's (:mod:`apf_physics.sim.engine`): an episode that starts
    within the goal tolerance of a target has ended at its start, and its next step reports
    it terminated and reached, without moving it and with reward 0.
    """

    def __init__(self, worlds: Sequence[World], num: int, observer: ObserverConfig, weights: RewardWeights,
                 formation: FormationSpec | None = None, max_steps: int | None = None, trap: TrapOption = None,
                 robot: RobotOptions = RobotOptions()):
        self.worlds = list(worlds)
        self.num = int(num)
        self.weights = weights
        self.robot = robot
        self.team = FormationTeam(formation, self.num) if formation is not None else None
        # a formation of unicycles: the followers' rule in its unicycle form, one per slot (made at start)
        self.unicycle_followers: list[UnicycleFollowers | None] | None = (
            [None] * self.num if formation is not None and robot.unicycle is not None else None)
        robots = 1 if self.team is None else self.team.robots
        self.stepper = Stepper(self.worlds, self.num, robots, max_steps=max_steps, trap=trap_detector(trap),
                               unicycle=robot.unicycle)
        # the potential at the robots (the reward's W4) and their visits: the window observer, whatever they see
        self.observer = Observer(observer, self.num, self.worlds, track_visits=bool(weights.revisit))
        self.sensor = make_observation(robot.observation, self.observer, robot.lidar, robot.unicycle, self.worlds)
        self._observation = _zeros(self.sensor.space(), self.num)
        self._u = np.zeros(self.num)     # the potential at each leader (its window's centre)
        self._moved = np.zeros((self.num, 2))   # each leader's last displacement (a holonomic robot's velocity)

    @property
    def positions(self) -> np.ndarray:
        """(N, m, 2) every robot's position."""
        return self.stepper.positions

    @property
    def world_of(self) -> np.ndarray:
        return self.stepper.world_of

    def observation_space(self) -> spaces.Space:
        """One slot's observation space (:meth:`~apf_physics.sensing.kinds.ObservationKind.space`)."""
        return self.sensor.space()

    def seed(self, seeds: Sequence[int | None]) -> None:
        """Restart the sensors' noise, slot ``i`` from ``seeds[i]`` (the environments call it at a seeded reset)."""
        self.sensor.seed(seeds)

    def start(self, slots: np.ndarray, world_ids: np.ndarray, leaders: np.ndarray,
              headings: np.ndarray | None = None, observe: bool = True) -> None:
        """Begin episodes in ``slots``, leaders at ``leaders`` (k, 2) in ``worlds[world_ids]``
        (unicycles headed ``headings`` (k,), default toward the nearest target).

        ``observe=False``: their observations are left to the caller's next :meth:`_observe`
        (:meth:`step` observes the slots it restarts with the ones it moved, in one call).

        Raises:
            UserError: A formation's followers find no free position near its leader.
        """
        slots = np.asarray(slots, np.intp).reshape(-1)
        world_ids = np.asarray(world_ids, np.intp).reshape(-1)
        leaders = np.asarray(leaders, float).reshape(-1, 2)
        worlds = list(map(self.worlds.__getitem__, world_ids.tolist()))
        if self.team is None:
            positions = leaders[:, None, :]
        else:
            positions = np.stack([self.team.starts(world, p[None])[0] for world, p in zip(worlds, leaders)])
            if self.unicycle_followers is None:
                self.team.reset(slots, worlds, positions)
        if headings is not None:
            headings = np.repeat(np.asarray(headings, float).reshape(-1, 1), positions.shape[1], axis=1)
        self.stepper.start(slots, positions, world_ids, headings=headings)
        if self.unicycle_followers is not None:
            states = self.stepper.states()
            for slot, world in zip(slots.tolist(), worlds):
                followers = UnicycleFollowers(world, self.team.spec, self.robot.unicycle)
                followers.reset(states[slot])
                self.unicycle_followers[slot] = followers
        self.observer.reset(slots, leaders, worlds)
        self.sensor.reset(slots, leaders, worlds)
        self._moved[slots] = 0.0
        if observe:
            self._observe(None if self.num == 1 else slots)   # (a batch of one: its one slot)

    def _robots(self, slots: np.ndarray | None) -> Robots:
        """What the sensors know of the leaders of ``slots`` (None: all)."""
        rows = slice(None) if slots is None else slots
        stepper = self.stepper
        unicycle = self.robot.unicycle is not None
        return Robots(stepper.positions[rows, 0], slots, stepper.steps[rows],   # the steps: where moving obstacles are
                      headings=stepper.headings[rows, 0] if unicycle else None,
                      velocity=stepper.drive[rows, 0] if unicycle else self._moved[rows],
                      others=stepper.positions[rows, 1:] if stepper.robots_per_slot > 1 else None)

    def _observe(self, slots: np.ndarray | None) -> None:
        """Refresh the observations (and the potential at the leader) of ``slots`` (None: all)."""
        robots = self._robots(slots)
        obs = self.sensor.observe(robots)
        u = self.sensor.centre_potential(obs)   # what the observation already read, else an unscaled sample
        if u is None:
            u = self.observer.potential_at(robots.positions, slots, robots.steps)
        if slots is None:
            self._u = u.astype(float)
            self._observation = obs
        else:  # copy on write: an array handed out by step() is never changed afterwards
            self._u[slots] = u
            self._observation = _with_rows(self._observation, slots, obs)

    def observation(self, slots: np.ndarray | int | None = None) -> np.ndarray | dict:
        """The current observations (or those of ``slots``; an int: that slot's alone): (N, C, k, k)
        windows, (N, K + 5) ranges, or ``{"window": ..., "lidar": ...}``; never changed afterwards."""
        if slots is None:
            return self._observation
        if isinstance(self._observation, dict):
            return {name: part[slots] for name, part in self._observation.items()}
        return self._observation[slots]

    def step(self, actions: np.ndarray | int, restart: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
             ) -> TaskStep:
        """Advance every running slot by its action (slots not running do not move; a batch of
        one may be given its action as an int).

        ``restart``: ``(slots, world_ids, leaders)`` of slots not running, to :meth:`start` anew
        once the others have moved (a vector env's automatic reset); the observation returned
        is theirs at the new start. Their observations are made with the moved slots' in one call.
        """
        if restart is not None and not len(restart[0]):
            restart = None
        commands = self.robot.commands(actions, self.num)
        before = self.stepper.positions[:, 0]
        if self.team is None:
            commands = commands[:, None, :]
        elif self.unicycle_followers is not None:
            commands = self._unicycle_team(commands)
        else:
            commands = self.team.commands(self.stepper.positions, commands, self.stepper.running)
        report = self.stepper.step(commands)
        moved, everyone = report.moved, report.everyone
        slots = None if everyone else np.flatnonzero(moved)
        leaders = report.positions[:, 0]
        if self.sensor.reads_velocity and self.robot.unicycle is None:   # a holonomic robot's velocity
            self._moved = np.where(moved[:, None], leaders - before, self._moved)
        revisits = None
        if self.observer.memory is not None:
            revisits = np.zeros(self.num)
            revisits[moved] = self.observer.visit(leaders[moved], slots)
        u_before = self._u
        if not everyone:   # the others' U stays as it was, in a new array (u_before is handed to the reward)
            self._u = self._u.copy()
        observed = slots
        if restart is not None:
            self.start(*restart, observe=False)
            now = moved.copy()
            now[restart[0]] = True
            observed = None if now.all() else np.flatnonzero(now)
        self._observe(observed)
        walked = np.sqrt(np.sum((leaders - before) ** 2, axis=1)) if self.weights.length else None
        reward, terms = rewards(self.weights, report.collided, report.reached, u_before, self._u,
                                revisits if self.weights.revisit else None, walked, None if everyone else moved)
        ended = report.ended
        terminated, truncated, trapped = _ends(ended, self.stepper.outcome)
        robot_contact = report.contacts.robot.reshape(self.num, -1).any(axis=1) if report.contacts.touched \
            else ended & False
        return TaskStep(self.observation(), reward, terminated, truncated, terms, report.reached, report.collided,
                        moved, robot_contact, trapped)

    def _unicycle_team(self, leader: np.ndarray) -> np.ndarray:
        """(N, m, 2) every unicycle's ``(v, ω)``: each running leader's command within the limits and
        slowed to its followers' :meth:`~apf_physics.control.tracking.UnicycleFollowers.leader_cap` (as in
        ``eval``'s rollouts), the followers' by :meth:`~apf_physics.control.tracking.UnicycleFollowers.drive`
        (which stops a leader about to meet one of its followers)."""
        limits = self.robot.unicycle
        states = self.stepper.states()
        running = self.stepper.running
        v, omega = limits.clamp(leader[:, 0], leader[:, 1], states[:, 0, 3], states[:, 0, 4])
        v, omega = limits.clamp(np.minimum(v, leader_caps(states, running, self.unicycle_followers, limits)), omega,
                                states[:, 0, 3], states[:, 0, 4])
        return team_drive(states, np.where(running, v, 0.0), np.where(running, omega, 0.0), running,
                          self.unicycle_followers)

    def distance(self) -> np.ndarray:
        """(N,) each leader's distance to the nearest target of its world, after the last start or step."""
        return self.stepper.last_distance


class FormationsTask:
    """Several formations of one world at once (its ``formations:``), each to its own target.

    What the PettingZoo environment steps: one :class:`~apf_physics.sim.engine.Stepper` slot per
    formation, all in one crowd (their robots meet), the followers' rule and the right of way
    of :class:`~apf_physics.control.formation.Formations`, one observer row per agent.

    Args:
        world: A world with ``formations``.
        observer: How observations are built; an agent sees the robots of the other
            formations (``"leaders"``) or all the other robots (``"all"``) as discs.
        weights: Reward weights.
        agents: ``"leaders"``: one agent per formation, its followers follow by their rule and
            every move gets the right of way; ``"all"``: every robot is an agent, moved as told.
        max_steps: Truncate after this many steps (None: never).
        trap: Truncate a formation whose leader the trap detector finds stuck (:func:`trap_detector`;
            default None: no trap rule).
        observation: What each agent observes (:data:`~apf_physics.sensing.kinds.OBSERVATIONS`); its
            range sensor sees every other robot.
        lidar: The range sensor's beams.
    """

    def __init__(self, world: World, observer: ObserverConfig, weights: RewardWeights, agents: str = "leaders",
                 max_steps: int | None = None, trap: TrapOption = None, observation: str = "window",
                 lidar: LidarConfig = LidarConfig()):
        if agents not in ("leaders", "all"):
            raise ValueError(f"agents must be 'leaders' or 'all', got {agents!r}")
        if not world.formations:
            raise ValueError(f"{world.label}: the world has no 'formations'")
        self.world = world
        self.formations = Formations(world)
        self.weights = weights
        self.mode = agents
        count, m = self.formations.count, self.formations.robots
        self.stepper = Stepper(self.formations.worlds, count, m, max_steps=max_steps, trap=trap_detector(trap),
                               crowds=[0] * count)
        if agents == "leaders":
            self.members = [(f, 0) for f in range(count)]
        else:
            self.members = [(f, r) for f in range(count) for r in range(self.formations.sizes[f])]
        self.names = [f"leader_{f}" if agents == "leaders" else f"robot_{f}_{r}" for f, r in self.members]
        self._formation = np.array([f for f, _ in self.members], np.intp)
        self._robot = np.array([f * m + r for f, r in self.members], np.intp)
        self.observer = Observer(observer, len(self.members), self.formations.worlds, track_visits=bool(weights.revisit))
        self.sensor = make_observation(observation, self.observer, lidar, None, self.formations.worlds)
        # which robots each agent has in its field: the other formations' (and, when every robot is an
        # agent, its own formation's too)
        m = self.formations.robots
        mine = self._formation[:, None] == np.arange(count * m)[None, :] // m
        self._in_field = ~mine if agents == "leaders" else np.ones_like(mine)
        self._in_field[np.arange(len(self.members)), self._robot] = False

    def start(self) -> None:
        """Every formation at its start (followers behind their leaders)."""
        initial = self.formations.starts()
        slots = np.arange(self.formations.count)
        self.stepper.start(slots, initial, world_ids=slots, present=self.formations.present)
        self.formations.reset(initial)
        self.step_count = 0
        positions = self._agent_positions()
        agents = np.arange(len(self.members))
        worlds = [self.formations.worlds[f] for f in self._formation]
        self.observer.reset(agents, positions, worlds)
        self.sensor.reset(agents, positions, worlds)
        self._obs, self._u = self._observe()

    def _agent_positions(self) -> np.ndarray:
        return self.stepper.positions.reshape(-1, 2)[self._robot]

    def _observe(self) -> tuple[np.ndarray | dict, np.ndarray]:
        """Every agent's observation, and U at it (in its formation's field, with the others' discs)."""
        robots = self.stepper.positions.reshape(-1, 2)
        present = self.stepper.physics.present
        seen = present[None, :] & (np.arange(len(robots))[None, :] != self._robot[:, None])
        shown = np.where(seen[..., None], robots[None], np.nan)                       # (A, N, 2)
        discs = np.where((self._in_field & present[None, :])[..., None], robots[None], np.nan)
        agents = Robots(robots[self._robot], None, self.step_count, others=shown, discs=discs)
        obs = self.sensor.observe(agents)
        u = self.sensor.centre_potential(obs)
        if u is None:
            u = np.array([self.observer.potential_at(agents.positions[a:a + 1], np.array([a]), self.step_count,
                                                     d[~np.isnan(d[:, 0])])[0] for a, d in enumerate(discs)])
        return obs, np.asarray(u, float)

    def step(self, actions: np.ndarray) -> TaskStep:
        """Every agent's move (agents of ended formations: ignored)."""
        moves = ACTIONS[np.asarray(actions, dtype=np.intp).reshape(len(self.members))]
        positions = self.stepper.positions
        running = self.stepper.running
        before = self._agent_positions()
        if self.mode == "leaders":
            commands = self.formations.commands(positions, moves, running, self.step_count)
        else:
            commands = np.zeros(positions.shape)
            commands.reshape(-1, 2)[self._robot] = moves
        report = self.stepper.step(commands)
        self.step_count += 1
        self.formations.watch(report.positions, report.moved, self.step_count)
        for a in range(len(self.members)):
            if report.moved[self._formation[a]]:
                self.observer.visit(self._agent_positions()[a:a + 1], np.array([a]))
        u_before = self._u
        self._obs, self._u = self._observe()
        moved = report.moved[self._formation]
        touched = report.contacts.any[self._robot] if self.mode == "all" else report.collided[self._formation]
        reached = report.reached[self._formation]
        walked = np.hypot(*(self._agent_positions() - before).T) if self.weights.length else None
        reward, terms = rewards(self.weights, touched & moved, reached & moved, u_before, self._u, None, walked, moved)
        terminated, truncated, trapped = _ends(report.ended[self._formation], self.stepper.outcome[self._formation])
        robot_contact = report.contacts.robot[self._robot]
        return TaskStep(self._obs, reward, terminated, truncated, terms, reached, touched, moved,
                        robot_contact, trapped)


class FleetTask:
    """A fleet on one map (:mod:`apf_physics.control.fleet`): every robot an agent with a goal of its own,
    the observations and rewards of POGEMA (what :class:`~apf_physics.envs.parallel.FleetParallelEnv` steps).

    Each step the agents' moves (:data:`~apf_physics.world.kinematics.ACTIONS`) go through the fleet's
    rule with each agent's own move first and staying second
    (:func:`~apf_physics.control.fleet.fleet_moves`, in an order drawn each step): a move that would bring
    two robots within ``2·radius + SAFETY`` of each other, or into an obstacle, is refused and the agent
    stays (POGEMA's soft collisions, with bodies); then one :class:`~apf_physics.sim.engine.Stepper` step
    moves them all, one crowd in one pymunk space.

    Args:
        world: The map (and its ``robots:``, the default starts and goals).
        num_agents: Robots when the starts are drawn (default: the world's robots).
        obs_radius: The window's half side in steps (POGEMA's ``obs_radius``).
        on_target: ``"finish"``: an agent that reaches its goal is done (its robot stays there, a body
            in the others' way); ``"restart"``: it is given its next goal at once (lifelong).
        max_steps: Truncate every agent after this many steps.
    """

    def __init__(self, world: World, num_agents: int | None = None, obs_radius: int = 5, on_target: str = "finish",
                 max_steps: int = 256):
        if on_target not in ("finish", "restart"):
            raise UserError(f"on_target must be 'finish' or 'restart', got {on_target!r}")
        if world.robots is None and num_agents is None:
            raise UserError(f"{world.label}: no robots: give the world 'robots:' or the environment num_agents=N")
        self.world, self.on_target, self.max_steps = world, on_target, int(max_steps)
        self.count = len(world.robots) if num_agents is None else int(num_agents)
        origin = world.robots.starts[0] if world.robots is not None else (0.5, 0.5)
        self.lattice = Lattice.of(world, origin)
        self.radius = int(obs_radius)
        self.shape = (3, 2 * self.radius + 1, 2 * self.radius + 1)
        self.blocked = np.pad(~self.lattice.free.reshape(self.lattice.shape), self.radius, constant_values=True)

    def draw(self, rng: np.random.Generator, random_starts: bool) -> tuple[np.ndarray, np.ndarray]:
        """Start and goal nodes: the world's robots', or drawn (distinct, in the largest connected region)."""
        if not random_starts and self.world.robots is not None:
            placed = place_fleet(self.world, self.world.robots.first(self.count), self.on_target == "finish")
            return placed.starts, placed.goals
        regions = self.lattice.regions()
        region = np.flatnonzero(regions == np.bincount(regions[regions >= 0]).argmax())
        if self.count > len(region):
            raise UserError(f"{self.world.label}: {self.count} agents, but the map's largest region has {len(region)} nodes")
        starts, goals = rng.choice(region, self.count, replace=False), rng.choice(region, self.count, replace=False)
        return starts, goals

    def start(self, rng: np.random.Generator, random_starts: bool = False) -> None:
        self.rng = rng
        starts, self.goals = self.draw(rng, random_starts)
        self.stream = GoalStream(self.lattice, starts, int(rng.integers(2**31))) if self.on_target == "restart" else None
        n = self.count
        self.stepper = Stepper([self.world], n, 1, crowds=[0] * n, arrival="continue")
        self.stepper.start(np.arange(n), self.lattice.points(starts)[:, None, :])
        self.nodes = starts.copy()
        self.done = np.zeros(n, bool)
        self.steps = 0

    def observe(self) -> np.ndarray:
        """(N, 3, k, k) float32: obstacles (and the map's outside), the other robots, the goal (on the
        window's border when beyond it); row 0 is the window's top (north up), as POGEMA's."""
        rows, cols = self.lattice.shape
        r, c = np.divmod(self.nodes, cols)
        k = 2 * self.radius + 1
        windows = np.lib.stride_tricks.sliding_window_view(self.blocked, (k, k))
        agents = np.zeros((rows + 2 * self.radius, cols + 2 * self.radius), bool)
        agents[r + self.radius, c + self.radius] = True
        out = np.zeros((self.count, *self.shape), np.float32)
        out[:, 0] = windows[r, c]
        out[:, 1] = np.lib.stride_tricks.sliding_window_view(agents, (k, k))[r, c]
        out[:, 1, self.radius, self.radius] = 0.0            # not itself
        gr, gc = np.divmod(self.goals, cols)
        dr = np.clip(gr - r, -self.radius, self.radius) + self.radius
        dc = np.clip(gc - c, -self.radius, self.radius) + self.radius
        out[np.arange(self.count), 2, dr, dc] = 1.0
        return out[:, :, ::-1, :].copy()                       # north up

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The agents' moves; returns ``(reward, terminated, truncated, refused, collided)``, each (N,)."""
        actions = np.asarray(actions, np.intp).reshape(self.count)
        prefs = np.full((self.count, 9), -1, np.intp)
        prefs[:, 0], prefs[:, 1] = actions, STAY
        prefs[~self.lattice.ok[self.nodes, actions] & (actions != STAY), 0] = STAY
        moves = fleet_moves(self.lattice, self.nodes, prefs, self.rng.permutation(self.count), pinned=self.done)
        report = self.stepper.step(ACTIONS[moves][:, None, :])
        self.steps += 1
        self.nodes = self.lattice.nearest(report.positions[:, 0])
        arrived = (self.nodes == self.goals) & ~self.done
        reward = arrived.astype(float)
        if self.stream is not None:
            for i in np.flatnonzero(arrived).tolist():
                self.goals[i] = self.stream.next(i, int(self.nodes[i]))
            terminated = np.zeros(self.count, bool)
        else:
            terminated = arrived
            self.done |= arrived
        truncated = np.full(self.count, self.steps >= self.max_steps) & ~terminated
        collided = report.contacts.any.copy() if report.contacts.touched else np.zeros(self.count, bool)
        return reward, terminated, truncated, (moves != actions), collided
