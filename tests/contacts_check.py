"""What the contact tests assert after every control step: how far robots overlap obstacles, the
map's edge and each other, and whether a robot's centre passed through another robot."""

import numpy as np

OBSTACLE_OVERLAP = 0.01   # at most this far into an obstacle or past the map's edge, at the end of a step
ROBOT_OVERLAP = 0.02      # at most this much overlap of two robots, at the end of a step


def overlaps(physics, before, t_end=None, after=None):
    """``(obstacle (N,), robot (N,), crossed (N,))`` after a step of ``physics`` from ``before``:
    each robot's overlap with obstacles and the map's edge, its largest overlap with a robot it
    meets, and whether its straight path from ``before`` came within half a radius of another's
    (a centre through another robot; robots that slide around each other within one step can
    come within a radius of each other on straight paths, but not within half of one unless they
    turn about each other by more than 150° in one step)."""
    m = physics.robots_per_slot
    after = physics.positions if after is None else np.asarray(after, float)   # the positions judged
    n = physics.num_robots
    obstacle = np.zeros(n)
    robot = np.zeros(n)
    crossed = np.zeros(n, bool)
    present = physics.present
    t = physics.slots.time if t_end is None else t_end
    for s in range(physics.num_slots):
        mine = np.arange(s * m, (s + 1) * m)
        mine = mine[present[mine]]
        world = physics.worlds[s]
        obstacle[mine] = world.robot_radius - world.clearance(after[mine], t[s] if np.ndim(t) else t)
    # groups of robots that meet: a slot of several, or a crowd of slots
    groups = {}
    for s in range(physics.num_slots):
        key = ("crowd", int(physics.crowd[s])) if physics.slots.shared[s] else ("slot", s)
        groups.setdefault(key, []).extend(range(s * m, (s + 1) * m))
    for robots in groups.values():
        robots = np.array(robots)
        robots = robots[present[robots]]
        if len(robots) < 2:
            continue
        r = physics.slots.radius[robots // m]
        a, b = after[robots], before[robots]
        d = np.hypot(*(a[:, None] - a[None]).transpose(2, 0, 1))
        np.fill_diagonal(d, np.inf)
        robot[robots] = np.max(r[:, None] + r[None] - d, axis=1)
        # closest approach of the two straight paths over the step
        r0 = b[:, None] - b[None]
        dr = (a - b)[:, None] - (a - b)[None]
        aa = np.sum(dr * dr, -1)
        s_ = np.clip(np.where(aa > 0, -np.sum(r0 * dr, -1) / np.where(aa > 0, aa, 1), 0), 0, 1)
        c = np.hypot(*(r0 + s_[..., None] * dr).transpose(2, 0, 1))
        np.fill_diagonal(c, np.inf)
        crossed[robots] = np.any(c < 0.5 * r[:, None], axis=1)
    return obstacle, robot, crossed


def assert_contacts_hold(physics, before, t_end=None):
    obstacle, robot, crossed = overlaps(physics, before, t_end)
    assert obstacle.max(initial=0) <= OBSTACLE_OVERLAP, f"a robot {obstacle.max():.4f} inside an obstacle or the edge"
    assert robot.max(initial=0) <= ROBOT_OVERLAP, f"robots overlap by {robot.max():.4f}"
    assert not crossed.any(), "a robot passed through another"
