"""``apf_physics/Navigate-v0``: one robot, one world, the thesis's learning problem (SPEC §2)."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from apf_physics.actions import ACTIONS, ACTION_NAMES
from apf_physics.envs.batch import NavigationBatch
from apf_physics.envs.options import StartChooser, WorldSpec, check_starts, resolve_worlds
from apf_physics.envs.reward import TERMS, reward_weights

__all__ = ["ACTIONS", "ACTION_NAMES", "NavigateEnv"]


class NavigateEnv(gym.Env):
    """A disc robot in an artificial potential field, moved through pymunk physics, that must reach a target.

    ## Description

    The thesis's learning problem (SPEC §2): the robot sees a window of the potential field
    around itself and picks one of nine unit moves. Obstacles and the map's edge are solid
    (pymunk); touching them ends the episode. Planning by gradient descent gets trapped in the
    field's local minima; a learner can escape them.

    ## Action Space

    ``Discrete(9)``, in the thesis's order (Table 1): 0 up (0,+1), 1 down (0,−1), 2 left
    (−1,0), 3 right (+1,0), 4 left-up (−1,+1), 5 left-down (−1,−1), 6 right-up (+1,+1),
    7 right-down (+1,−1), 8 stay. Each becomes a velocity command held for one control step.

    ## Observation Space

    ``Box(-inf, inf, (1, k, k), float32)``: the potential U sampled bilinearly from the
    world's cached raster at spacing 1 around the robot's centre; element ``[0, i, j]`` is
    the point ``(x + j − k//2, y + k//2 − i)`` (row 0 at the top). Points inside obstacles or
    outside the map read ``world.u_wall``, the map's highest potential. Raw values, not
    normalised (learners scale them).

    With ``memory=True`` the space is ``Box(-inf, inf, (2, k, k), float32)``: channel 0 is
    the potential window above and channel 1 the robot's visit memory over the same points,
    ``min(n, 4) / 4`` where ``n`` counts the control steps (and the reset) that ended with the
    robot's centre in the point's 1×1 cell of the map; points outside the map read 1. The
    counts are cleared at every reset (:class:`~apf_physics.observation.VisitMemory`). A
    reactive policy sees where it has been and can learn to leave a potential well.

    ## Rewards

    ``R = W1 + W2 + W3 + W4`` (SPEC eq. 15–16), returned by name in ``info["reward_terms"]``:
    ``collision`` W1 when touching an obstacle or the edge, ``target`` W2 on reaching the
    target, ``step`` W3 every step, ``potential`` W4 = β·(U(P_{n+1}) − U(P_n)). Presets:
    ``"thesis-fixed"`` (Table 3: −1000, 1000, −1, β −4) and ``"thesis-general"`` (Table 4:
    −10, 10, −0.2, β −20), or a dict ``{w1, w2, w3, beta}``.

    ## Starting State

    ``starts="world"``: the world's start positions in turn (random if it has none);
    ``"random"``: a uniformly drawn free position; or an explicit ``(S, 2)`` array, in turn.
    With a list of worlds, one is drawn per reset. ``reset(seed=...)`` makes everything
    that follows deterministic.

    ## Episode End

    Terminated when the robot's centre is within ``goal_tolerance`` of a target (success) or
    it touches an obstacle or the map's edge (collision, W1). Truncated after ``tt`` steps,
    set by the registration's ``max_episode_steps`` (100, thesis Tables 3–4).

    ## Arguments

    ```python
    gymnasium.make("apf_physics/Navigate-v0", world="worlds/fixed20.yaml", obs_size=11,
                   reward="thesis-fixed", starts="world", render_mode=None)
    ```

    - ``world``: a world file path, a :class:`~apf_physics.world.World`, or a list of them.
    - ``obs_size``: the window side k (odd; 11 in Table 3, 9 in Table 4).
    - ``reward``: a preset name or weights (see Rewards).
    - ``starts``: see Starting State.
    - ``resolution``: raster nodes per unit for the observation (default 4).
    - ``render_mode``: ``"rgb_array"`` for OpenCV-drawn frames.
    - ``memory``: add the visit-memory channel (see Observation Space; default False).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, world: WorldSpec | None = None, obs_size: int = 11, reward: Any = "thesis-fixed",
                 starts: Any = "world", resolution: int = 4, render_mode: str | None = None,
                 memory: bool = False):
        self.worlds = resolve_worlds(world)
        self.obs_size = int(obs_size)
        self.weights = reward_weights(reward)
        self.chooser = StartChooser(check_starts(starts))
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']}, got {render_mode!r}")
        self.render_mode = render_mode
        self.action_space = spaces.Discrete(len(ACTIONS))
        self.memory = bool(memory)
        channels = 2 if self.memory else 1
        self.observation_space = spaces.Box(-np.inf, np.inf, (channels, self.obs_size, self.obs_size), np.float32)
        self._batch = NavigationBatch(self.worlds, 1, self.obs_size, self.weights, resolution, memory=self.memory)
        self._episode = 0
        self._trail: list[np.ndarray] = []
        self._steps = 0

    @property
    def world(self):
        """The world of the current episode."""
        return self.worlds[self._batch.world_of[0]]

    @property
    def position(self) -> np.ndarray:
        return self._batch.positions[0].copy()

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is not None:
            self._episode = 0
        w, start = self.chooser.choose(self.worlds, self.np_random, self._episode)
        if options and "start" in options:
            start = np.asarray(options["start"], dtype=float)
        self._episode += 1
        self._batch.set_world(0, w)
        self._batch.place(np.array([0]), start[None])
        self._trail = [start.copy()]
        self._steps = 0
        return self._batch.observation()[0], self._get_info()

    def step(self, action):
        result = self._batch.step(np.array([int(action)]))
        self._steps += 1
        if self.render_mode is not None:  # the trail is only drawn
            self._trail.append(self._batch.positions[0].copy())
        info = self._get_info()
        info["reward_terms"] = {name: float(result.terms[name][0]) for name in TERMS}
        info["success"] = bool(result.reached[0])
        info["collision"] = bool(result.collided[0])
        return result.observation[0], float(result.reward[0]), bool(result.terminated[0]), False, info

    def _get_info(self) -> dict:
        return {"position": self._batch.positions[0].copy(), "world": self.world.name,
                "distance": float(self._batch.distance[0])}

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        from apf_physics.render.drawing import Snapshot, draw_frame, field_image

        snap = Snapshot(self._batch.positions[:1], ("single",), (np.asarray(self._trail),),
                        (f"{self.world.name}  step {self._steps}",))
        return draw_frame(field_image(self.world), snap)
