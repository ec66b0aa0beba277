"""``apf_physics/Navigate-v0``: one robot, one world, the thesis's learning problem (Model §2)."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from apf_physics.control.shield import ACTION_NAMES, ACTIONS
from apf_physics.envs.options import StartChooser, WorldSpec, observer_config, resolve_worlds, robot_options
from apf_physics.envs.reward import TERMS, reward_weights
from apf_physics.envs.task import NavigationTask, TrapOption
from apf_physics.sensing.observation import ObserverConfig
from apf_physics.render.drawing import Snapshot, draw_frame, field_image

__all__ = ["ACTIONS", "ACTION_NAMES", "NavigateEnv"]

_SLOT = np.zeros(1, np.intp)   # the task's one slot
_SLOT.flags.writeable = False


class NavigateEnv(gym.Env):
    """A disc robot in an artificial potential field, moved through pymunk physics, that must reach a target.

    ## Description

    The thesis's learning problem (Model §2): the robot sees a window of the potential field
    around itself and picks one of nine unit moves. Obstacles and the map's edge are solid
    (pymunk); touching them ends the episode. Planning by gradient descent gets trapped in the
    field's local minima; a learner can escape them.

    ## Action Space

    ``Discrete(9)``, in the thesis's order (Table 1): 0 up (0,+1), 1 down (0,−1), 2 left
    (−1,0), 3 right (+1,0), 4 left-up (−1,+1), 5 left-down (−1,−1), 6 right-up (+1,+1),
    7 right-down (+1,−1), 8 stay (``apf_physics.control.shield.ACTION_NAMES``). Each becomes a
    velocity command held for one control step.

    ## Observation Space

    ``Box(-inf, inf, (1, k, k), float32)``: the potential U sampled bilinearly from the
    world's cached raster at spacing 1 around the robot's centre; element ``[0, i, j]`` is
    the point ``(x + j − k//2, y + k//2 − i)`` (row 0 at the top). Points inside obstacles or
    outside the map read ``world.u_wall``, the map's highest potential. Raw values by default
    (the package's networks scale them themselves); ``obs_scale="log"`` gives a bounded
    ``Box(-1, 1)``: ``sign(d)·log(1 + |d|) / log(1 + D)`` with ``d = U − U(robot)`` and
    ``D`` the world's range of U, so the robot's own point reads 0, downhill is negative
    and walls read close to 1.

    With ``memory=True`` there is a second channel, ``(2, k, k)``: the robot's visit memory
    over the same points, ``min(n, 4) / 4`` where ``n`` counts the control steps (and the
    reset) that ended with the robot's centre in the point's 1×1 cell of the map; points
    outside the map read 1. The counts are cleared at every reset
    (:class:`~apf_physics.sensing.observation.VisitMemory`). A reactive policy sees where it has been
    and can learn to leave a potential well.

    With ``previous=True`` the channel after the potential is the same window of the field
    one control step earlier (robot where it is now, obstacles where they were): in a world
    with moving obstacles the difference of the two channels shows where each is going.
    Channels come in the order potential, previous, memory.

    ## Rewards

    ``R = W1 + W2 + W3 + W4 (+ W5 + W6)`` (Model eq. 15–16), returned by name in
    ``info["reward_terms"]``: ``collision`` W1 when touching an obstacle or the edge,
    ``target`` W2 on reaching the target, ``step`` W3 every step, ``potential``
    W4 = β·(U(P_{n+1}) − U(P_n)), and the project's ``revisit`` W5 and ``length`` W6
    (:class:`~apf_physics.envs.reward.RewardWeights`). Presets: ``"thesis-fixed"`` (Table 3:
    −1000, 1000, −1, β −4), ``"thesis-general"`` (Table 4: −10, 10, −0.2, β −20) and
    ``"general"`` (Table 3's plus W5 = −50, W6 = −40), or a dict of the weights.

    ## Starting State

    ``starts="world"``: one of the world's start positions (random free positions if it has
    none); ``"random"``: a uniformly drawn free position farther than the goal tolerance from
    the targets; or an explicit ``(S, 2)`` array of starts. Each reset draws the start (and,
    with a list of worlds, the world) from the environment's ``np_random``: ``reset(seed=k)``
    makes the episode and all that follow reproducible, and different seeds give different
    starts. ``reset(options={"start": i})`` takes start row ``i`` instead,
    ``options={"start": [x, y]}`` a position, ``options={"world": j}`` world ``j``.

    ## Episode End

    The rules of ``apf-physics eval`` (:mod:`apf_physics.sim.engine`, one definition for both).
    Terminated when the robot's centre is within ``goal_tolerance`` of a target (success) or
    it touches an obstacle or the map's edge (collision, W1). Truncated after ``tt`` steps,
    set by the registration's ``max_episode_steps`` (100, thesis Tables 3–4). A start already
    within ``goal_tolerance`` of a target (``options={"start": [x, y]}`` or an array of
    starts can give one) is an episode reached at its start, in 0 steps: the first step
    returns ``terminated=True`` and ``info["success"]`` without moving the robot, reward 0.

    ``trap`` (default None: no trap rule, as in training) adds ``eval``'s trap detector:
    ``"oscillation"`` truncates the episode once the robot's last 10 positions lie within
    1.5 of their mean, ``"descent"`` also once U stopped dropping over them, and a
    :class:`~apf_physics.sim.engine.TrapDetector` sets the window and radius; ``info["trapped"]``
    then says whether it did. With the detector of a planner's rule and window (and the step
    limit of ``eval``) an episode driven by the planner's moves ends as ``eval``'s does.

    ## Arguments

    ```python
    gymnasium.make("apf_physics/Navigate-v0", world="fixed20", obs_size=11,
                   reward="thesis-fixed", starts="world", render_mode=None)
    ```

    - ``world``: a world file path, a bundled world's name, a :class:`~apf_physics.world.World`,
      or a list of them.
    - ``obs_size``: the window side k (odd; 11 in Table 3, 9 in Table 4).
    - ``reward``: a preset name or weights (see Rewards).
    - ``starts``: see Starting State.
    - ``resolution``: raster nodes per unit for the observation (default 4).
    - ``memory``: add the visit-memory channel (see Observation Space; default False).
    - ``previous``: add the window of the field one step earlier, as the channel after the
      potential (default False): in a world with moving obstacles the difference of the two
      shows where each obstacle is going.
    - ``obs_scale``: ``"raw"`` (default) or ``"log"`` (see Observation Space).
    - ``observer``: an :class:`~apf_physics.sensing.observation.ObserverConfig` (or its dict) instead
      of ``obs_size``, ``resolution``, ``memory`` and ``obs_scale``, e.g. a model's.
    - ``trap``: None (default), ``"oscillation"``, ``"descent"`` or a
      :class:`~apf_physics.sim.engine.TrapDetector` (see Episode End).
    - ``render_mode``: ``"rgb_array"`` for OpenCV-drawn frames.

    ``info`` holds ``position``, ``world`` (its name) and ``distance`` (to the nearest target)
    after every reset and step, and after a step also ``reward_terms``, ``success`` and
    ``collision`` (and ``trapped``, with a ``trap`` detector).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, world: WorldSpec | None = None, obs_size: int = 11, reward: Any = "thesis-fixed",
                 starts: Any = "world", resolution: int = 4, render_mode: str | None = None,
                 memory: bool = False, previous: bool = False, obs_scale: str = "raw",
                 observer: ObserverConfig | dict | None = None, trap: TrapOption = None,
                 action: str = "discrete", kinematics: str | None = None, observation: str = "window",
                 lidar: Any = None, limits: Any = None):
        self.worlds = resolve_worlds(world)
        self.robot = robot_options(self.worlds, action, kinematics, observation, lidar, limits)
        self.observer = observer_config(obs_size, resolution, memory, obs_scale, observer, previous)
        self.weights = reward_weights(reward)
        self.chooser = StartChooser(starts, self.worlds)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']}, got {render_mode!r}")
        self.render_mode = render_mode
        self.action_space = self.robot.action_space()
        self.task = NavigationTask(self.worlds, 1, self.observer, self.weights, trap=trap, robot=self.robot)
        """The episodes this environment steps (stepper, physics, observer): for tools and tests to look inside."""
        self.observation_space = self.task.observation_space()
        self._trail: list[np.ndarray] = []
        self._steps = 0
        self._world_name = self.worlds[0].name   # the current episode's world's (set at reset)

    @property
    def world(self):
        """The world of the current episode."""
        return self.worlds[self.task.world_of[0]]

    @property
    def position(self) -> np.ndarray:
        return self.task.positions[0, 0].copy()

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is not None:
            self.task.seed([seed])
        w, start = self.chooser.choose(self.np_random, options)
        self.task.start(_SLOT, np.array([w]), start[None])
        self._world_name = self.worlds[w].name
        self._trail = [start.copy()]
        self._steps = 0
        return self.task.observation(0), self._get_info()

    def step(self, action):
        result = self.task.step(int(action) if self.robot.action == "discrete" else action)
        self._steps += 1
        if self.render_mode is not None:  # the trail is only drawn
            self._trail.append(self.position)
        info = self._get_info()
        info["reward_terms"] = dict(zip(TERMS, result.terms[:, 0].tolist()))
        info["success"] = bool(result.reached[0])
        info["collision"] = bool(result.collided[0])
        if self.task.stepper.trap is not None:
            info["trapped"] = bool(result.trapped[0])
        return (self.task.observation(0), float(result.reward[0]), bool(result.terminated[0]), bool(result.truncated[0]),
                info)

    def _get_info(self) -> dict:
        info = {"position": self.task.positions[0, 0].copy(), "world": self._world_name,
                "distance": float(self.task.distance()[0])}
        if self.robot.unicycle is not None:
            info["heading"] = float(self.task.stepper.headings[0, 0])
        return info

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        snap = Snapshot(self.task.positions[0, :1], ("single",), (np.asarray(self._trail),),
                        (f"{self.world.name}  step {self._steps}",), self._steps,
                        headings=self.task.stepper.headings[0, :1] if self.robot.unicycle is not None else None)
        return draw_frame(field_image(self.world), snap)

