"""A Q-network that plans: a learned cost map, value iteration over it, and a per-move head.

The thesis's second direction of future work is an observation that is an image map of the
world. This network takes one (:class:`~apf_physics.sensing.mapview.MapView`): every node of a
grid over the map (``resolution`` per unit) carries the robot's clearance there and whether a
target is within reach. It has three parts, all learned:

1. **Cost map.** Two convolutions turn the node features into a cost per unit of length
   ``κ(x) > 0`` (where the robot would rather not go: near walls, in narrow places).
2. **Value iteration** (a value-iteration network, Tamar et al., NIPS 2016, in its shortest-
   path form): ``V(x) ← max(V(x), max_n V(x + n) − |n|·(κ(x) + κ(x + n))/2)`` over the 8
   neighbours, with ``V = 0`` at the target nodes, repeated until nothing changes. ``−V`` is the
   learned cost to go. The iterations run without gradients to the fixed point, then a few
   more with them (the gradient of a fixed point, truncated: enough for a cost map that is a
   local function of the features).
3. **Head.** Each candidate move ``a`` of the robot at ``p`` is scored, with weights shared by
   all moves, from what the robot knows: the change of ``V`` (sampled bilinearly over the
   free nodes) from ``p`` to ``p + a`` (with a positive weight, so more value never scores
   less), the move's length, the change of the potential ``U``, whether it stays, and a
   small MLP of the clearance left along the move (the same local check as the shield,
   moving obstacles included). The scores are the action values.

Nothing here searches the world's graph with A* or knows the optimal path: A* is the teacher
in training (:mod:`apf_physics.learning.imitation`), never consulted when the network acts. One
network serves every map size: the grid grows with the map and the iterations run until the
values settle.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from apf_physics.common.compiled import kernel
from apf_physics.world.search import shortest_costs

MAP_FEATURES = 2
"""Node features of a :class:`~apf_physics.sensing.mapview.MapView`: clearance margin, target."""
MOVE_FEATURES = 5
"""Per-move features of the head: ΔV, length, room, ΔU, stay."""
UNREACHED = -1e6
"""V of nodes with no way to a target (blocked, or cut off)."""
DV_CLIP = 4.0
"""|ΔV| fed to the head is clipped to this (a move is at most √2 long)."""


def _neighbours(resolution: int) -> list[tuple[int, int, float]]:
    return [(dr, dc, math.hypot(dr, dc) / resolution) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if dr or dc]


class MapNetwork(nn.Module):
    """Learned cost map + value iteration + per-move head (see the module's docstring).

    Args:
        resolution: Grid nodes per world unit of the map view (of its training; its cost map's scale).
        channels: Hidden channels of the cost map's first convolution.
        hidden: Widths of the head's hidden layers.
        negative_slope: Leaky ReLU slope.
        moves: Name of the move set (:data:`~apf_physics.world.kinematics.MOVE_KINDS`).
        dv_clip: |ΔV| the head reads is clipped to this.
        least_resolution: Moves onto nodes: the graph it plans on has at least this many nodes per
            step (default ``resolution``).
    """

    def __init__(self, resolution: int = 2, channels: int = 8, hidden: Sequence[int] = (32, 32),
                 negative_slope: float = 0.01, moves: str = "fine", dv_clip: float = DV_CLIP,
                 least_resolution: int | None = None):
        super().__init__()
        self.arch = {"type": "map", "resolution": int(resolution), "channels": int(channels),
                     "hidden": [int(h) for h in hidden], "negative_slope": float(negative_slope), "moves": str(moves)}
        """Everything needed to build this network again (saved with its weights)."""
        if dv_clip != DV_CLIP:    # (files of networks that clip at DV_CLIP do not name it)
            self.arch["dv_clip"] = float(dv_clip)
        if least_resolution is not None:
            self.arch["least_resolution"] = int(least_resolution)
        self.dv_clip = float(dv_clip)
        self.resolution = int(resolution)
        self.least_resolution = int(least_resolution or resolution)
        """Nodes per step of the grid it plans on, at least (moves onto nodes:
        :func:`~apf_physics.sim.nodegraph.resolution_for`)."""
        self.negative_slope = float(negative_slope)
        self.cost_in = nn.Conv2d(MAP_FEATURES, channels, kernel_size=3, padding=1)
        self.cost_out = nn.Conv2d(channels, 1, kernel_size=1)
        # the head: linear in ΔV (with a positive weight: a move that gains more value never
        # scores less, all else equal), the length, ΔU and staying; a small MLP of the room
        self.value_weight = nn.Parameter(torch.tensor(math.log(math.e - 1.0)))
        self.linear = nn.Linear(MOVE_FEATURES - 2, 1)     # length, ΔU, stay
        sizes = [1, *self.arch["hidden"]]
        self.hidden = nn.ModuleList(nn.Linear(a, b) for a, b in zip(sizes[:-1], sizes[1:]))
        self.head = nn.Linear(sizes[-1], 1)
        with torch.no_grad():   # start from "every free place costs about its length"
            self.cost_out.bias.fill_(math.log(math.e - 1.0))
            self.cost_out.weight.mul_(0.1)

    # -- the cost map and the values ---------------------------------------------------------
    def cost(self, features: torch.Tensor) -> torch.Tensor:
        """(R, C) cost per unit length at each node, from (F, R, C) node features; at least 0.1."""
        x = F.leaky_relu(self.cost_in(features[None]), self.negative_slope)
        return F.softplus(self.cost_out(x))[0, 0] + 0.1

    def values(self, features: torch.Tensor, free: torch.Tensor, goal: torch.Tensor,
               grad_iterations: int = 0, max_iterations: int | None = None,
               links: torch.Tensor | None = None, resolution: int | None = None,
               with_cost: bool = False) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        """(R, C) V over the grid: minus the learned cost to go to the nearest target node.

        Args:
            features: (F, R, C) node features.
            free: (R, C) bool, nodes where the robot fits.
            goal: (R, C) bool, free nodes within reach of a target.
            grad_iterations: Iterations run with gradients after the fixed point is reached.
            max_iterations: Bellman updates without gradients, at most (default: none; the fixed point is
                found by :func:`fixed_point`, however long the paths).
            links: (8, R, C) bool, which edges (in :func:`_neighbours`' order) may be followed
                (:class:`~apf_physics.sim.nodegraph.NodeGraph`); None: every edge between free nodes.
            resolution: Nodes per unit of this grid (default: :attr:`resolution`, the network's own).
            with_cost: Also return the cost map ``κ`` (R, C).
        """
        kappa = self.cost(features)
        edges = [(dr, dc, w * 0.5 * (kappa + _shift(kappa, dr, dc, float("inf"))))
                 for dr, dc, w in _neighbours(resolution or self.resolution)]
        if links is not None:   # an edge the robot cannot follow costs without end
            edges = [(dr, dc, torch.where(links[k], cost, torch.full_like(cost, float("inf"))))
                     for k, (dr, dc, cost) in enumerate(edges)]
        with torch.no_grad():
            plain = [(dr, dc, e.detach()) for dr, dc, e in edges]
            if max_iterations is None:
                v = fixed_point(plain, free, goal).to(kappa.dtype)
            else:
                v = torch.where(goal, 0.0, UNREACHED).to(kappa.dtype)
                for k in range(max_iterations):
                    new = _bellman_update(v, plain, free, goal)
                    if k % 8 == 7 and torch.equal(new, v):
                        break
                    v = new
        for _ in range(grad_iterations):
            v = _bellman_update(v, edges, free, goal)
        return (v, kappa) if with_cost else v

    # -- the head -------------------------------------------------------------------------------
    def scores(self, move_features: torch.Tensor) -> torch.Tensor:
        """(N, M) action values from (N, M, MOVE_FEATURES) per-move features (:func:`move_features`)."""
        dv, room = move_features[..., 0], move_features[..., 2:3]
        x = room
        for layer in self.hidden:
            x = F.leaky_relu(layer(x), self.negative_slope)
        rest = move_features[..., [1, 3, 4]]
        return F.softplus(self.value_weight) * dv + self.linear(rest)[..., 0] + self.head(x)[..., 0]


def replan(network: MapNetwork, features: torch.Tensor, free: torch.Tensor, held: torch.Tensor,
           values: torch.Tensor, extra_cost: torch.Tensor | float = 0.0, resolution: int | None = None,
           links: torch.Tensor | None = None) -> torch.Tensor:
    """V over a patch of the grid in which something changed (other robots stand in it), the
    patch's edge held at the values of the whole map.

    Value iteration over the patch alone: the network's cost map from the patch's ``features``
    (plus ``extra_cost``), the nodes in ``held`` (the patch's edge, and its target nodes) keeping
    their ``values``, the others settled by Bellman updates (:func:`_settle`, compiled) until nothing
    changes: the fixed point of :func:`_bellman_update`, to the bit. A node's value is then the best of
    going to the patch's edge (and on from there as the map's values say) or to a target within
    it, around what is blocked in the patch.

    Args:
        network: The map network.
        features: (F, R, C) the patch's node features.
        free: (R, C) bool: the patch's nodes where the robot fits.
        held: (R, C) bool: nodes whose value is kept.
        values: (R, C) the map's V over the patch (read at ``held``).
        extra_cost: Added to the learned cost per unit length, per node ((R, C) or a number).
        resolution: Nodes per unit of the patch's grid (default: the network's own).
        links: (8, R, C) bool, which edges may be followed (as :meth:`MapNetwork.values` takes them).

    Returns:
        (R, C) float32 V over the patch (:data:`UNREACHED` where no way leads).
    """
    with torch.no_grad():
        kappa = network.cost(features) + extra_cost
        neighbours = _neighbours(resolution or network.resolution)
        costs = torch.stack([w * 0.5 * (kappa + _shift(kappa, dr, dc, float("inf"))) for dr, dc, w in neighbours])
        if links is not None:   # an edge the robot cannot follow costs without end
            costs = torch.where(links, costs, torch.full_like(costs, float("inf")))
        held = (held & free).numpy()
        v = np.where(held, values.numpy(), np.float32(UNREACHED)).astype(np.float32)
        _settle(v, held, free.numpy(), costs.numpy().astype(np.float32),
                np.array([(dr, dc) for dr, dc, _ in neighbours], np.intp))
        return torch.from_numpy(v)


@kernel
def _settle(v, held, free, costs, steps):
    """Bellman updates ``v(x) ← max(v(x), v(x + n) − cost_n(x))`` of the free nodes not ``held``, in
    place, in forward and backward passes over the grid in turn until nothing changes
    (``costs[k]``: the edge to the neighbour ``steps[k]``)."""
    rows, cols = v.shape
    changed = True
    while changed:
        changed = False
        for backwards in range(2):
            for i in range(rows * cols):
                flat = rows * cols - 1 - i if backwards else i
                r, c = flat // cols, flat % cols
                if held[r, c] or not free[r, c]:
                    continue
                best = v[r, c]
                for k in range(steps.shape[0]):
                    nr, nc = r + steps[k, 0], c + steps[k, 1]
                    if 0 <= nr < rows and 0 <= nc < cols:
                        offer = v[nr, nc] - costs[k, r, c]
                        if offer > best:
                            best = offer
                if best > v[r, c]:
                    v[r, c] = best
                    changed = True


def _shift(x: torch.Tensor, dr: int, dc: int, fill: float) -> torch.Tensor:
    """``y[r, c] = x[r + dr, c + dc]`` (``fill`` beyond the edge)."""
    padded = F.pad(x[None, None], (1, 1, 1, 1), value=fill)[0, 0]
    rows, cols = x.shape
    return padded[1 + dr:1 + dr + rows, 1 + dc:1 + dc + cols]


def fixed_point(edges: list, free: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
    """The fixed point of :func:`_bellman_update`, without updating the whole grid again and again.

    ``−V`` is a shortest-path cost to the goal nodes with positive edge costs, so it is found
    by :func:`~apf_physics.world.search.shortest_costs` (a compiled Dijkstra search: every node settled
    once), and long paths (a maze's) are followed to their end. The values are the updates' own, to the bit: each is
    ``V(x + n) − cost``, in float32.

    Args:
        edges: ``(dr, dc, cost)`` per neighbour: ``cost[r, c]`` of the edge ``(r, c) → (r+dr, c+dc)``.
        free: (R, C) bool.
        goal: (R, C) bool.

    Returns:
        (R, C) float32 V: 0 at the goal nodes, ``UNREACHED`` where no path leads (or blocked).
    """
    steps = [(dr, dc, cost.numpy()) for dr, dc, cost in edges]
    cost_to_go = shortest_costs(free.numpy(), np.flatnonzero(goal.numpy().ravel()), steps, np.float32)
    reached = free.numpy().ravel() & (cost_to_go <= -UNREACHED)
    v = np.where(reached, -cost_to_go, np.float32(UNREACHED)).astype(np.float32)
    v[goal.numpy().ravel()] = 0.0
    return torch.from_numpy(v.reshape(free.shape))


def _bellman_update(v: torch.Tensor, edges: list, free: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
    """One Bellman update (a value-iteration step over the whole grid): each free node takes its best neighbour's value minus the edge's cost."""
    padded = F.pad(v[None, None], (1, 1, 1, 1), value=UNREACHED)[0, 0]
    rows, cols = v.shape
    best = v
    for dr, dc, cost in edges:
        best = torch.maximum(best, padded[1 + dr:1 + dr + rows, 1 + dc:1 + dc + cols] - cost)
    best = torch.where(free, best.clamp_min(UNREACHED), torch.full_like(best, UNREACHED))
    return torch.where(goal, torch.zeros_like(best), best)


def sample_values(v: torch.Tensor, free: torch.Tensor, origin: Sequence[float], resolution: int,
                  points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """V at ``points`` (K, 2): the best of the reached free nodes around each point, less the
    distance to it, ``max_n V(n) − |q − n|`` over the four corners of the point's cell.

    Unlike a bilinear blend (which, next to blocked nodes, weights the free ones anew and can
    make a short move look like a long gain), this continues V off the grid as a cost to go
    does: from any point, heading for its best corner never loses more value than distance.

    Returns:
        (K,) values and (K,) bool: whether any of the four nodes around the point was usable
        (else the value is :data:`UNREACHED`).
    """
    rows, cols = v.shape
    ij = (points - torch.as_tensor(origin, dtype=points.dtype)) * resolution
    c0, r0 = torch.floor(ij[:, 0]), torch.floor(ij[:, 1])
    fx, fy = ij[:, 0] - c0, ij[:, 1] - r0
    c0, r0 = c0.long(), r0.long()
    best = torch.full((len(points),), UNREACHED, dtype=v.dtype)
    usable = free & (v > UNREACHED / 2)
    for dr, dc in ((0, 0), (0, 1), (1, 0), (1, 1)):
        r, c = r0 + dr, c0 + dc
        inside = (r >= 0) & (r < rows) & (c >= 0) & (c < cols)
        rc, cc = r.clamp(0, rows - 1), c.clamp(0, cols - 1)
        ok = inside & usable[rc, cc]
        distance = torch.hypot(fx - dc, fy - dr).to(v.dtype) / resolution
        best = torch.maximum(best, torch.where(ok, v[rc, cc] - distance, torch.full_like(best, UNREACHED)))
    found = best > UNREACHED / 2
    return best, found


def values_between(v: torch.Tensor, kappa: torch.Tensor, free: torch.Tensor, origin: Sequence[float], resolution: int,
                   points: torch.Tensor) -> torch.Tensor:
    """V at ``points`` (K, 2) between nodes, as the values themselves continue: from the best of the
    four nodes around each point, less the learned cost of the straight way there,
    ``max_n V(n) − κ(n)·|q − n|`` (:data:`UNREACHED` where none is usable).

    The map network that moves onto nodes reads V at its moves' ends on nodes; this is V where the
    robot stands when it is not on one (at its start), in the same units, so that no move looks
    like a loss against a value read at another rate (:func:`sample_values` charges 1 per unit)."""
    rows, cols = v.shape
    ij = (points - torch.as_tensor(origin, dtype=points.dtype)) * resolution
    c0, r0 = torch.floor(ij[:, 0]), torch.floor(ij[:, 1])
    fx, fy = ij[:, 0] - c0, ij[:, 1] - r0
    c0, r0 = c0.long(), r0.long()
    best = torch.full((len(points),), UNREACHED, dtype=v.dtype)
    usable = free & (v > UNREACHED / 2)
    for dr, dc in ((0, 0), (0, 1), (1, 0), (1, 1)):
        r, c = r0 + dr, c0 + dc
        inside = (r >= 0) & (r < rows) & (c >= 0) & (c < cols)
        rc, cc = r.clamp(0, rows - 1), c.clamp(0, cols - 1)
        ok = inside & usable[rc, cc]
        distance = torch.hypot(fx - dc, fy - dr).to(v.dtype) / resolution
        best = torch.maximum(best, torch.where(ok, v[rc, cc] - kappa[rc, cc] * distance, torch.full_like(best, UNREACHED)))
    return best


def move_features(v_here: torch.Tensor, v_there: torch.Tensor, found: torch.Tensor, lengths: torch.Tensor,
                  room: torch.Tensor, du: torch.Tensor, dv_clip: float = DV_CLIP) -> torch.Tensor:
    """(N, M, MOVE_FEATURES) head inputs.

    Args:
        v_here: (N,) V at the robots.
        v_there: (N, M) V at the end of each move.
        found: (N, M) whether ``v_there`` could be sampled.
        lengths: (M,) move lengths, or (N, M) when each robot has moves of its own.
        room: (N, M) clearance left along each move beyond the robot's radius and the safety margin.
        du: (N, M) change of the potential over each move, signed-log scaled.
        dv_clip: |ΔV| is clipped to this (the network's :attr:`MapNetwork.dv_clip`).
    """
    here_ok = v_here > UNREACHED / 2
    dv = torch.where(found & here_ok[:, None], v_there - v_here[:, None], torch.full_like(v_there, -dv_clip))
    dv = dv.clamp(-dv_clip, dv_clip)
    n, m = v_there.shape
    lengths = lengths.expand(n, m)
    stay = (lengths == 0).to(v_there.dtype)
    return torch.stack([dv, lengths, room.clamp(-1.0, 1.0), du, stay], dim=-1)
