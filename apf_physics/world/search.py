"""Shortest paths on a grid over the free space: the oracle for reachability and path length.

The map is covered by a grid of nodes (``resolution`` per unit). A node is free when a robot
centred there keeps ``robot_radius + margin`` from every obstacle and the map's edge (one
vectorised :meth:`World.clearance` call for all nodes). Nodes are 8-connected with Euclidean
edge costs. Because the clearance is 1-Lipschitz, every point of an edge between two free
nodes keeps at least ``robot_radius + margin − 0.5·√2/resolution`` from everything, which is
more than the robot's radius for the default ``margin`` (0.2 at 4 nodes per unit).

One multi-source shortest-path search from the nodes at the targets (:func:`shortest_paths`) gives, for every node, the cost
to go to the nearest reachable target and the next node on the way there; every start of a
world is then served from that one search. The grid path is pulled taut by line-of-sight
shortcuts (segments whose sampled clearance stays above ``robot_radius + los_margin``), so
paths are not jagged and their length is close to the true shortest length.

The A* planner (:class:`~apf_physics.planners.astar.AStarPlanner`) executes these paths
through the physics; the world generator uses :func:`reachable` and
:func:`shortest_path_length`.
"""

from __future__ import annotations

import heapq
import math

import cv2
import numpy as np

from apf_physics.common import geometry
from apf_physics.common.compiled import kernel
from apf_physics.world.field import Grid
from apf_physics.world.core import World
from apf_physics.world.kinematics import ACTIONS

RESOLUTION = 4        # grid nodes per world unit
MARGIN = 0.2          # safety margin on top of the robot's radius at grid nodes [units]
LOS_MARGIN = 0.1      # safety margin on top of the robot's radius along shortcut segments [units]
LOS_SPACING = 0.1     # sample spacing along a segment for line-of-sight checks [units]
START_REACH = 1.0     # a start connects to free nodes at most this far away [units]

# 8-connected neighbourhood: (row offset, column offset, cost in cells)
_NEIGHBOURS = [(dr, dc, math.hypot(dr, dc)) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if dr or dc]


def shortest_paths(free: np.ndarray, sources: np.ndarray, steps, dtype=np.float64) -> tuple[np.ndarray, np.ndarray]:
    """Shortest paths over a grid's free nodes to the nearest of ``sources``, with positive edge costs.

    A label-correcting search, vectorised: each round relaxes the edges into the nodes whose
    cost just fell, so a round costs what the wavefront holds, and rounds run until no cost
    falls (one per edge of the longest path). Costs are sums along each path in its order, and
    among equal ways the next node is the one Dijkstra would settle first (lowest cost, then
    lowest index), so the paths are Dijkstra's.

    Args:
        free: (R, C) bool: the nodes that may be entered.
        sources: Flat indices of the nodes of cost 0.
        steps: ``(dr, dc, cost)`` per neighbour: the cost of the edge from ``(r, c)`` to
            ``(r + dr, c + dc)``, a number or an (R, C) array.
        dtype: The costs' type (float32 reproduces float32 sweeps to the bit).

    Returns:
        ``(cost (R·C,), next (R·C,))``: the cost to the nearest source (inf: none reachable) and
        the next node on the way (−1 at sources and unreachable nodes).
    """
    rows, cols = free.shape
    free_flat = np.asarray(free, bool).ravel()
    cost = np.full(rows * cols, np.inf, dtype)
    nxt = np.full(rows * cols, -1, np.intp)
    sources = np.asarray(sources, np.intp).ravel()
    cost[sources] = 0
    edges = [(dr, dc, np.broadcast_to(np.asarray(c, dtype), (rows, cols)).ravel()) for dr, dc, c in steps]
    frontier = np.unique(sources)
    while len(frontier):
        r, c = np.divmod(frontier, cols)
        nodes, values, via = [], [], []
        for dr, dc, edge in edges:          # x = y − (dr, dc) reaches y over its edge (dr, dc)
            ok = (r >= dr) & (r - dr < rows) & (c >= dc) & (c - dc < cols)
            y = frontier[ok]
            x = y - (dr * cols + dc)
            value = cost[y] + edge[x]
            offer = free_flat[x] & (value <= cost[x])
            nodes.append(x[offer])
            values.append(value[offer])
            via.append(y[offer])
        nodes, values, via = np.concatenate(nodes), np.concatenate(values), np.concatenate(via)
        if not len(nodes):
            break
        # per node its best offer: the lowest cost, then (as Dijkstra settles them) the via node
        # of lowest cost, then of lowest index
        order = np.lexsort((via, cost[via], values, nodes))
        nodes, values, via = nodes[order], values[order], via[order]
        first = np.concatenate([[True], nodes[1:] != nodes[:-1]])
        nodes, values, via = nodes[first], values[first], via[first]
        lower = values < cost[nodes]
        held = nxt[nodes]
        tie = ~lower & (held >= 0) & ((cost[via] < cost[held]) | ((cost[via] == cost[held]) & (via < held)))
        cost[nodes[lower]] = values[lower]
        nxt[nodes[lower | tie]] = via[lower | tie]
        frontier = nodes[lower]
    return cost, nxt


@kernel
def node_distances(ok, offsets, lengths, source):
    """Dijkstra over a graph of nodes with up to M moves each: every node's cost to reach ``source``.

    Args:
        ok: (n, M) bool: move ``m`` from node ``u`` to ``u + offsets[m]`` is allowed; moves are taken
            to be allowed both ways (a fleet's lattice: :class:`~apf_physics.control.fleet.Lattice`).
        offsets: (M,) each move's change of node index.
        lengths: (M,) each move's cost.
        source: The node of cost 0.

    Returns:
        (n,) float64 costs (inf where ``source`` cannot be reached).
    """
    n = ok.shape[0]
    cost = np.full(n, np.inf)
    done = np.zeros(n, np.bool_)
    heap_cost = np.empty(8 * n + 1)
    heap_node = np.empty(8 * n + 1, np.int64)
    size = 0
    cost[source] = 0.0
    heap_cost[0], heap_node[0] = 0.0, source
    size = 1
    while size > 0:
        c, u = heap_cost[0], heap_node[0]
        size -= 1
        # sift the last entry down from the root
        last_c, last_u = heap_cost[size], heap_node[size]
        i = 0
        while True:
            child = 2 * i + 1
            if child >= size:
                break
            if child + 1 < size and heap_cost[child + 1] < heap_cost[child]:
                child += 1
            if heap_cost[child] >= last_c:
                break
            heap_cost[i], heap_node[i] = heap_cost[child], heap_node[child]
            i = child
        heap_cost[i], heap_node[i] = last_c, last_u
        if done[u]:
            continue
        done[u] = True
        for m in range(ok.shape[1]):
            if not ok[u, m] or lengths[m] <= 0:
                continue
            v = u + offsets[m]
            value = c + lengths[m]
            if value < cost[v]:
                cost[v] = value
                # sift up
                i = size
                size += 1
                while i > 0:
                    parent = (i - 1) // 2
                    if heap_cost[parent] <= value:
                        break
                    heap_cost[i], heap_node[i] = heap_cost[parent], heap_node[parent]
                    i = parent
                heap_cost[i], heap_node[i] = value, v
    return cost


def shortest_costs(free: np.ndarray, sources: np.ndarray, steps, dtype=np.float32) -> np.ndarray:
    """The costs of :func:`shortest_paths` (without the next nodes), by a compiled Dijkstra search.

    The same numbers to the bit: both are the least fixed point of ``cost[x] = min over edges of
    cost[x + (dr, dc)] + edge[x]``, summed in ``dtype`` (rounding is monotonic, and edges are not
    negative, so Dijkstra's settled costs are final). Every node is settled once: a large map's
    long paths cost what the map holds, not one vectorised round per edge of the longest path.
    """
    rows, cols = free.shape
    dr = np.array([d[0] for d in steps], np.int64)
    dc = np.array([d[1] for d in steps], np.int64)
    edges = np.stack([np.broadcast_to(np.asarray(d[2], dtype), (rows, cols)).ravel() for d in steps]).astype(dtype)
    cost = np.full(rows * cols, np.inf, dtype)
    _settle_costs(np.ascontiguousarray(free, np.bool_).ravel(), rows, cols,
                  np.unique(np.asarray(sources, np.int64).ravel()), dr, dc, edges, cost)
    return cost


@kernel
def _settle_costs(free, rows, cols, sources, dr, dc, edges, cost):
    """Dijkstra from ``sources`` over the free nodes: ``cost[x] = cost[y] + edges[k, x]`` for ``y = x +
    (dr[k], dc[k])``, in ``cost``'s type, written into ``cost``."""
    n = rows * cols
    done = np.zeros(n, np.bool_)
    heap_cost = np.empty(dr.shape[0] * n + len(sources) + 1, cost.dtype)
    heap_node = np.empty(dr.shape[0] * n + len(sources) + 1, np.int64)
    size = 0
    for s in sources:
        cost[s] = 0
        i = size
        size += 1
        while i > 0 and heap_cost[(i - 1) // 2] > 0:
            heap_cost[i], heap_node[i] = heap_cost[(i - 1) // 2], heap_node[(i - 1) // 2]
            i = (i - 1) // 2
        heap_cost[i], heap_node[i] = cost[s], s
    while size > 0:
        c, y = heap_cost[0], heap_node[0]
        size -= 1
        last_c, last_u = heap_cost[size], heap_node[size]
        i = 0
        while True:
            child = 2 * i + 1
            if child >= size:
                break
            if child + 1 < size and heap_cost[child + 1] < heap_cost[child]:
                child += 1
            if heap_cost[child] >= last_c:
                break
            heap_cost[i], heap_node[i] = heap_cost[child], heap_node[child]
            i = child
        heap_cost[i], heap_node[i] = last_c, last_u
        if done[y] or c > cost[y]:
            continue
        done[y] = True
        r, col = y // cols, y % cols
        for k in range(dr.shape[0]):
            xr, xc = r - dr[k], col - dc[k]
            if xr < 0 or xr >= rows or xc < 0 or xc >= cols:
                continue
            x = xr * cols + xc
            if not free[x] or done[x]:
                continue
            value = cost[y] + edges[k, x]
            if value < cost[x]:
                cost[x] = value
                i = size
                size += 1
                while i > 0:
                    parent = (i - 1) // 2
                    if heap_cost[parent] <= value:
                        break
                    heap_cost[i], heap_node[i] = heap_cost[parent], heap_node[parent]
                    i = parent
                heap_cost[i], heap_node[i] = value, x


class SearchGrid:
    """The free-space grid of one world and the shortest paths to its targets.

    Build it with :meth:`of` (cached per world and settings).

    Attributes:
        world: The world.
        grid: Node positions (``Grid``: origin, resolution, shape).
        clearance: (rows, cols) clearance at each node.
        free: (rows, cols) True where a robot fits with the safety margin.
        margin: The safety margin at nodes on top of the robot's radius.
    """

    def __init__(self, world: World, resolution: int = RESOLUTION, margin: float = MARGIN):
        self.world = world
        self.grid = Grid.covering((0.0, 0.0), world.size, resolution)
        self.margin = float(margin)
        self.clearance = world.node_clearance(resolution)
        self.free = self.clearance >= world.robot_radius + self.margin
        self._labels: np.ndarray | None = None
        self._cost: np.ndarray | None = None
        self._next: np.ndarray | None = None
        self._goal_nodes: np.ndarray | None = None

    @classmethod
    def of(cls, world: World, resolution: int = RESOLUTION, margin: float = MARGIN) -> SearchGrid:
        """The (cached) search grid of ``world``."""
        return world.cached(("search_grid", int(resolution), float(margin)),
                            lambda: cls(world, resolution, margin))

    # -- nodes ------------------------------------------------------------------------------
    def node_xy(self, flat: np.ndarray) -> np.ndarray:
        """World coordinates of flat node indices (row-major)."""
        rows, cols = np.divmod(np.asarray(flat, dtype=np.intp), self.grid.shape[1])
        return self.grid.to_world(np.column_stack([cols, rows]))

    def nodes_near(self, point: np.ndarray, reach: float) -> np.ndarray:
        """Flat indices of the free nodes within ``reach`` of ``point``."""
        rows, cols = self.grid.shape
        c, r = self.grid.to_index(np.asarray(point, float).reshape(1, 2))[0]
        k = int(math.ceil(reach * self.grid.resolution)) + 1
        r0, r1 = max(0, int(math.floor(r)) - k), min(rows - 1, int(math.ceil(r)) + k)
        c0, c1 = max(0, int(math.floor(c)) - k), min(cols - 1, int(math.ceil(c)) + k)
        rr, cc = np.mgrid[r0:r1 + 1, c0:c1 + 1]
        flat = (rr * cols + cc).ravel()
        flat = flat[self.free.ravel()[flat]]
        near = np.hypot(*(self.node_xy(flat) - point).T) <= reach
        return flat[near]

    @property
    def goal_nodes(self) -> np.ndarray:
        """Free nodes close enough to a target that a robot there has reached it."""
        if self._goal_nodes is None:
            reach = 0.8 * self.world.goal_tolerance
            found = [self.nodes_near(t, reach) for t in self.world.targets]
            self._goal_nodes = np.unique(np.concatenate(found)) if found else np.zeros(0, np.intp)
        return self._goal_nodes

    # -- reachability (connected components: cheap) -----------------------------------------
    @property
    def labels(self) -> np.ndarray:
        """(rows*cols,) 8-connected component label of each node (0 = blocked)."""
        if self._labels is None:
            _, labels = cv2.connectedComponents(self.free.astype(np.uint8), connectivity=8)
            self._labels = labels.ravel()
        return self._labels

    def entry_nodes(self, start: np.ndarray) -> np.ndarray:
        """Free nodes a robot at ``start`` can move to in a straight line (within ``START_REACH``)."""
        start = np.asarray(start, float)
        nodes = self.nodes_near(start, START_REACH)
        if not len(nodes):
            return nodes
        r = self.world.robot_radius
        threshold = min(r + LOS_MARGIN, float(self.world.static_clearance(start[None])[0]))
        xy = self.node_xy(nodes)
        clear = self.world.path_clearance(np.broadcast_to(start, xy.shape), xy, 0.02) >= threshold
        return nodes[clear]

    def at_target(self, point: np.ndarray) -> bool:
        return bool(self.world.reached(point)[0])

    def reachable(self, start: np.ndarray) -> bool:
        """Whether a target can be reached from ``start`` (connected components, no search)."""
        if self.at_target(start):
            return True
        goals = self.goal_nodes
        entries = self.entry_nodes(start)
        if not len(goals) or not len(entries):
            return False
        return bool(np.intersect1d(self.labels[entries], self.labels[goals]).size)

    # -- shortest paths (Dijkstra from the targets) ------------------------------------------
    def _search(self) -> None:
        """Multi-source shortest paths from the goal nodes over the free nodes."""
        steps = [(dr, dc, w / self.grid.resolution) for dr, dc, w in _NEIGHBOURS]
        self._cost, self._next = shortest_paths(self.free, self.goal_nodes, steps)

    @property
    def cost_to_go(self) -> np.ndarray:
        """(rows*cols,) grid path length from each node to the nearest reachable target (inf: none)."""
        if self._cost is None:
            self._search()
        return self._cost

    def path(self, start: np.ndarray, t: float | None = None) -> np.ndarray | None:
        """Shortest path (shortcut waypoints) from ``start`` to the nearest reachable target.

        Args:
            start: The start.
            t: None: around the static obstacles (one Dijkstra search, shared by every start).
                A step: also around the moving obstacles where they are at that step, as if
                they stood still (an A* search of its own).

        Returns:
            (K, 2) waypoints, ``start`` first and a target (or a node within reach of it) last;
            None when no target is reachable.
        """
        start = np.asarray(start, float)
        if self.at_target(start):
            return start[None].copy()
        moving = t is not None and bool(self.world.moving)
        clearance = (lambda p: self.world.clearance(p, t)) if moving else self.world.static_clearance
        entries = self.entry_nodes(start)
        if moving:
            free = self.free.ravel() & ~self._moving_blocked(t)
            entries = entries[free[entries]]
        if not len(entries):
            return None
        if moving:
            chain = self._astar(start, entries, free)
            if chain is None:
                return None
        else:
            cost = self.cost_to_go
            total = cost[entries] + np.hypot(*(self.node_xy(entries) - start).T)
            best = int(np.argmin(total))
            if not math.isfinite(total[best]):
                return None
            chain = [int(entries[best])]
            nxt = self._next
            while nxt[chain[-1]] >= 0:
                chain.append(int(nxt[chain[-1]]))
        nodes = self._shortcut(self.node_xy(np.asarray(chain)), clearance)
        end = nodes[-1]
        target = self.world.nearest_target(end)[0]
        if self._clear(end, target, self.world.robot_radius + LOS_MARGIN, clearance):
            if np.hypot(*(nodes[-1] - target)) > 1e-9:
                nodes = np.vstack([nodes, target])
            if len(nodes) >= 3 and self._clear(nodes[-3], target, self.world.robot_radius + LOS_MARGIN, clearance):
                nodes = np.vstack([nodes[:-2], target])
        # The start may sit closer to an obstacle than the shortcut margin allows: shortcut the
        # start's own kink with its own clearance as the bar.
        threshold = min(self.world.robot_radius + LOS_MARGIN, float(clearance(start[None])[0]))
        while len(nodes) > 1 and self._clear(start, nodes[1], threshold, clearance):
            nodes = nodes[1:]
        return np.vstack([start, nodes])

    def _moving_blocked(self, t: float) -> np.ndarray:
        """(rows*cols,) nodes where a robot would not keep its radius plus the margin from a moving obstacle at step ``t``."""
        nodes = self.grid.node_points()
        blocked = np.zeros(len(nodes), bool)
        reach = self.world.robot_radius + self.margin
        for i in self.world.moving:
            obstacle = self.world.obstacles[i]
            shift = obstacle.motion.offset(t)
            lo, hi = obstacle.bounds
            near = np.flatnonzero(np.all((nodes >= lo + shift - reach) & (nodes <= hi + shift + reach), axis=1))
            if len(near):
                d, _ = obstacle.signed_distance(nodes[near] - shift)
                blocked[near[d < reach]] = True
        return blocked

    def _astar(self, start: np.ndarray, entries: np.ndarray, free: np.ndarray) -> list[int] | None:
        """A* over ``free`` nodes from ``entries`` (reached straight from ``start``) to the goal nodes."""
        rows, cols = self.grid.shape
        goals = set(self.goal_nodes[free[self.goal_nodes]].tolist())
        if not goals:
            return None
        h = 1.0 / self.grid.resolution
        targets = self.world.targets
        xy = self.node_xy(np.arange(rows * cols))
        heuristic = np.min(np.hypot(xy[:, None, 0] - targets[None, :, 0], xy[:, None, 1] - targets[None, :, 1]), axis=1)
        cost = {int(e): float(np.hypot(*(xy[e] - start))) for e in entries}
        came: dict[int, int] = {}
        heap = [(cost[e] + heuristic[e], e) for e in cost]
        heapq.heapify(heap)
        free_list = free.tolist()
        while heap:
            _, u = heapq.heappop(heap)
            if u in goals:
                chain = [u]
                while chain[-1] in came:
                    chain.append(came[chain[-1]])
                return chain[::-1]
            r, c = divmod(u, cols)
            for dr, dc, w in _NEIGHBOURS:
                rr, cc = r + dr, c + dc
                if 0 <= rr < rows and 0 <= cc < cols:
                    v = rr * cols + cc
                    if free_list[v]:
                        nd = cost[u] + w * h
                        if nd < cost.get(v, math.inf):
                            cost[v] = nd
                            came[v] = u
                            heapq.heappush(heap, (nd + heuristic[v], v))
        return None

    def _clear(self, a: np.ndarray, b: np.ndarray, threshold: float, clearance=None) -> bool:
        """Whether the segment ``a → b`` keeps ``threshold`` of clearance at samples ``LOS_SPACING`` apart."""
        clearance = clearance or self.world.static_clearance
        points, _ = geometry.segment_samples(a[None], b[None], LOS_SPACING)
        return bool(clearance(points).min() >= threshold)

    def _shortcut(self, nodes: np.ndarray, clearance=None) -> np.ndarray:
        """Pull a grid path taut: from each kept waypoint jump to the farthest one in sight."""
        if len(nodes) <= 2:
            return nodes
        clearance = clearance or self.world.static_clearance
        # Candidates are the nodes where the grid path turns, and its end.
        turn = np.flatnonzero(np.any(np.diff(nodes, 2, axis=0) != 0, axis=1)) + 1
        candidates = np.unique(np.concatenate([turn, [len(nodes) - 1]]))
        threshold = self.world.robot_radius + LOS_MARGIN
        kept = [0]
        i = 0
        while i < len(nodes) - 1:
            later = candidates[candidates > i]
            points, owner = geometry.segment_samples(np.broadcast_to(nodes[i], (len(later), 2)), nodes[later], LOS_SPACING)
            lowest = np.full(len(later), np.inf)
            np.minimum.at(lowest, owner, clearance(points))
            clear = lowest >= threshold
            # Fall back on the next grid node: grid edges between free nodes are safe.
            j = int(later[clear].max()) if clear.any() else i + 1
            kept.append(j)
            i = j
        return nodes[kept]


def _search_grid(world: World) -> SearchGrid:
    return SearchGrid.of(world)


def shortest_path(world: World, start: np.ndarray) -> np.ndarray | None:
    """Waypoints of a shortest collision-free path from ``start`` to the nearest reachable target.

    Returns:
        (K, 2) waypoints (``start`` first), or None when no target is reachable.
    """
    return _search_grid(world).path(np.asarray(start, float))


def shortest_path_length(world: World, start: np.ndarray) -> float | None:
    """Length of the shortcut grid path from ``start`` to the nearest reachable target, or None.

    The robot keeps its radius plus a small margin from obstacles and the map's edge along the
    path, so this is an upper bound on (and close to) the true shortest length with that clearance.
    """
    path = shortest_path(world, start)
    if path is None:
        return None
    return float(np.sum(np.hypot(*np.diff(path, axis=0).T)))


def reachable(world: World, start: np.ndarray) -> bool:
    """Whether a robot at ``start`` can reach a target of ``world`` (a free path exists)."""
    return _search_grid(world).reachable(np.asarray(start, float))


# -- time: the moving obstacles as the physics moves them, and searches over a robot's moves in time --------

TIME_SAMPLES = 16
"""Samples along each move (after its start) of the searches in time below."""
UNIT_MOVES = ACTIONS
"""The nine moves of Model §2, stay last."""


def physics_offsets(world: World, times: np.ndarray | float) -> np.ndarray:
    """``(..., M, 2)``: each moving obstacle's route offset at (fractional) steps ``times``, as the physics moves it.

    The engine puts a moving obstacle where its route has it at each whole step and moves it in a
    straight line at constant velocity to where the route has it at the next
    (:class:`~apf_physics.sim.physics.Physics`): between whole steps it cuts the route's corners.
    """
    times = np.asarray(times, float)
    lo = np.floor(times)
    a = world.moving_offsets(lo)
    b = world.moving_offsets(lo + 1.0)
    return a + (times - lo)[..., None, None] * (b - a)


def timed_move_clearance(world: World, starts: np.ndarray, moves: np.ndarray, t: float,
                         samples: int = TIME_SAMPLES, strict: bool = True, moving: bool = True) -> np.ndarray:
    """``(N, K)``: the clearance of the robot's centre along each move ``starts[i] → starts[i] + moves[k]``
    made during step ``t → t + 1``, every obstacle where the physics has it at each moment.

    Sampled at the start and ``samples`` evenly spaced moments of the move (the robot at
    ``start + s·move``, each moving obstacle at its offset at ``t + s``). ``strict``: a lower bound
    (the least sample lowered by half the spacing of the relative motion, as
    :func:`~apf_physics.control.shield.move_clearance` does); else the least sample itself (contact
    at a sample is certain below the robot's radius). ``moving`` False: the static obstacles alone.
    """
    starts = np.asarray(starts, float).reshape(-1, 2)
    moves = np.asarray(moves, float).reshape(-1, 2)
    n, k = len(starts), len(moves)
    s = np.arange(samples + 1) / samples
    points = starts[:, None, None, :] + s[None, None, :, None] * moves[None, :, None, :]      # (N, K, S, 2)
    flat = points.reshape(-1, 2)
    length = np.hypot(*moves.T)                                                                # (K,)
    best = world.static_clearance(flat, near=True).reshape(n, k, -1).min(axis=2)
    if strict:
        best = best - 0.5 * length[None, :] / samples
    if not moving or not world.moving or n == 0:
        return best
    offsets = physics_offsets(world, t + s)                                                    # (S, M, 2)
    lo_pts, hi_pts = flat.min(axis=0), flat.max(axis=0)
    for j, i in enumerate(world.moving):
        obstacle = world.obstacles[i]
        lo, hi = obstacle.bounds
        shift = offsets[:, j]
        reach = world.robot_radius + 3.0
        if np.any(lo + shift.min(axis=0) - reach > hi_pts) or np.any(hi + shift.max(axis=0) + reach < lo_pts):
            continue
        d, _ = obstacle.signed_distance((points - shift[None, None, :, :]).reshape(-1, 2))
        d = d.reshape(n, k, -1).min(axis=2)
        if strict:
            speed = float(np.max(np.hypot(*np.diff(shift, axis=0).T))) * samples
            d = d - 0.5 * (length[None, :] + speed) / samples
        best = np.minimum(best, d)
    return best


def escape_moves(world: World, position: np.ndarray, t0: int, steps: int, moves: np.ndarray = UNIT_MOVES,
                 margin: float = 0.0, strict: bool = True, samples: int = TIME_SAMPLES) -> list[int] | None:
    """A sequence of ``steps`` moves from ``position`` at step ``t0`` that touches nothing, or None.

    A breadth-first search of the time-expanded graph of the robot's moves: the positions a robot
    can be at after each step (``position`` plus sums of ``moves``, the same position reached by
    two sequences kept once), a move kept when its clearance (:func:`timed_move_clearance`, the
    moving obstacles as the physics moves them) exceeds ``robot_radius + margin`` (``strict``: as a
    lower bound, so that the sequence returned surely touches nothing; else at every sample, so
    that None means that every sequence touches something at a sample).

    Returns:
        The indices (into ``moves``) of one such sequence, or None when every sequence collides.
    """
    moves = np.asarray(moves, float).reshape(-1, 2)
    bar = world.robot_radius + margin
    frontier = np.asarray(position, float).reshape(1, 2)
    parents: list[tuple[np.ndarray, np.ndarray]] = []            # per step: (parent index, move index) of each node
    for step in range(int(steps)):
        clear = timed_move_clearance(world, frontier, moves, t0 + step, samples, strict)
        ok = clear >= bar if strict else clear > bar
        parent, move = np.nonzero(ok)
        if not len(parent):
            return None
        nxt = frontier[parent] + moves[move]
        _, keep = np.unique(np.round(nxt * 1e6).astype(np.int64), axis=0, return_index=True)
        keep = np.sort(keep)
        frontier = nxt[keep]
        parents.append((parent[keep], move[keep]))
    chain, node = [], 0
    for parent, move in reversed(parents):
        chain.append(int(move[node]))
        node = int(parent[node])
    return chain[::-1]


def _move_lattice(world: World, start: np.ndarray, moves: np.ndarray, margin: float, samples: int):
    """The lattice of the moves' sums through ``start`` over the map: ``(xy (V, 2), static (V, M)
    bool: each move from each node clear of the static obstacles by ``robot_radius + margin``,
    neighbour (V, M): the node each move leads to, or -1 off the lattice, target (T,): the nodes
    within the goal tolerance)``; None when the lattice or its targets are empty."""
    r = world.robot_radius
    w, h = world.size
    ix = np.arange(math.ceil(-start[0] + r), math.floor(w - start[0] - r) + 1)
    iy = np.arange(math.ceil(-start[1] + r), math.floor(h - start[1] - r) + 1)
    if not len(ix) or not len(iy):
        return None
    nx, ny = len(ix), len(iy)
    xy = np.stack(np.meshgrid(start[0] + ix, start[1] + iy, indexing="ij"), axis=-1).reshape(-1, 2)   # node = a*ny + b
    steps = moves.astype(int)
    static = timed_move_clearance(world, xy, moves, 0.0, samples, moving=False) >= r + margin
    a_idx, b_idx = np.divmod(np.arange(len(xy)), ny)
    na, nb = a_idx[:, None] + steps[None, :, 0], b_idx[:, None] + steps[None, :, 1]
    inside = (na >= 0) & (na < nx) & (nb >= 0) & (nb < ny)
    target = np.flatnonzero(world.distance_to_target(xy) < world.goal_tolerance)
    if not len(target):
        return None
    return xy, static & inside, np.where(inside, na * ny + nb, -1), target


def _lattice_costs(static: np.ndarray, neighbour: np.ndarray, target: np.ndarray, length: np.ndarray) -> np.ndarray:
    """(V,) each node's shortest path to a target on the lattice around the static obstacles alone
    (Dijkstra from the targets: moves are symmetric, u → v clear iff v → u clear)."""
    cost = np.full(len(static), np.inf)
    cost[target] = 0.0
    heap = [(0.0, int(v)) for v in target]
    static_l, neighbour_l = static.tolist(), neighbour.tolist()
    while heap:
        c, u = heapq.heappop(heap)
        if c > cost[u]:
            continue
        for k, v in enumerate(neighbour_l[u]):
            if v >= 0 and static_l[u][k] and length[k] > 0:
                nc = c + length[k]
                if nc < cost[v]:
                    cost[v] = nc
                    heapq.heappush(heap, (nc, v))
    return cost


def timed_path(world: World, start: np.ndarray, t0: int = 0, moves: np.ndarray = UNIT_MOVES,
               margin: float = 0.05, max_steps: int = 400, max_expansions: int = 60_000,
               samples: int = TIME_SAMPLES) -> np.ndarray | None:
    """A* in space and time on the known motion: the robot's positions at steps ``t0, t0 + 1, …`` to a target.

    The time-expanded graph of the robot's moves (a lattice of the moves' sums through ``start``
    × whole steps; waiting is the move ``(0, 0)``), each move kept when its lower-bound clearance
    (:func:`timed_move_clearance`: every moving obstacle where the physics has it at each moment)
    is at least ``robot_radius + margin``. Cost: a move's length, a wait 1 (a unit of time). The
    heuristic is the shortest path on the same lattice around the static obstacles alone
    (admissible: it is the cost without the moving obstacles), so that the search leaves the
    static shortest path only where something moves across it. It is what safe-interval path
    planning (Phillips & Likhachev 2011) computes on this graph, without its grouping of
    steps into safe intervals.

    Returns:
        ``(T + 1, 2)`` positions, ``start`` first and the first within ``goal_tolerance`` of a
        target last; None when no plan is found within ``max_steps`` steps and ``max_expansions``.
    """
    start = np.asarray(start, float).reshape(2)
    moves = np.asarray(moves, float).reshape(-1, 2)
    r = world.robot_radius
    if world.distance_to_target(start[None])[0] <= world.goal_tolerance:
        return start[None].copy()
    lattice = _move_lattice(world, start, moves, margin, samples)
    if lattice is None:
        return None
    xy, static, neighbour, target = lattice
    length = np.hypot(*moves.T)
    cost = _lattice_costs(static, neighbour, target, length)
    s0 = int(np.argmin(np.hypot(*(xy - start).T)))
    if not math.isfinite(cost[s0]):
        return None
    goal = np.zeros(len(xy), bool)
    goal[target] = True
    wait_cost = 1.0
    cost_l, static_l, neighbour_l = cost.tolist(), static.tolist(), neighbour.tolist()
    g = {(s0, 0): 0.0}
    came: dict[tuple[int, int], tuple[int, int]] = {}
    heap = [(cost_l[s0], 0.0, s0, 0)]
    expansions = 0
    while heap and expansions < max_expansions:
        f, gu, u, k = heapq.heappop(heap)
        if gu > g.get((u, k), math.inf):
            continue
        if goal[u]:
            chain = [(u, k)]
            while chain[-1] in came:
                chain.append(came[chain[-1]])
            return xy[[c[0] for c in chain[::-1]]]
        if k >= max_steps:
            continue
        expansions += 1
        allowed = np.asarray(static_l[u])
        if world.moving:
            allowed = allowed & (timed_move_clearance(world, xy[u][None], moves, t0 + k, samples)[0] >= r + margin)
        for m in np.flatnonzero(allowed).tolist():
            v = neighbour_l[u][m]
            if v < 0 or not math.isfinite(cost_l[v]):
                continue
            nd = gu + (length[m] if length[m] > 0 else wait_cost)
            key = (v, k + 1)
            if nd < g.get(key, math.inf):
                g[key] = nd
                came[key] = (u, k)
                heapq.heappush(heap, (nd + cost_l[v], nd, v, k + 1))
    return None

