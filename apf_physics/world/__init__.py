"""What a world is: the map, its obstacles (static and moving), targets, starts, the robot, and the
field over it (Model §1).

- :mod:`~apf_physics.world.core`: :class:`World`, the one object every layer above asks about the map
  (the potential, clearances, the world at step t, cached rasters).
- :mod:`~apf_physics.world.obstacles`, :mod:`~apf_physics.world.buckets`,
  :mod:`~apf_physics.world.spatial`, :mod:`~apf_physics.world.outlines`: shapes, and distances to
  many of them at a cost set by what is near.
- :mod:`~apf_physics.world.field`: ``U``, ``∇U`` and their rasters, one function per term.
- :mod:`~apf_physics.world.kinematics`: how a robot moves (Table 1's moves, unicycle arcs).
- :mod:`~apf_physics.world.search`: shortest paths over a world's free space (reachability, A*).
- :mod:`~apf_physics.world.io`: world files, map files and units, in and out.
- :mod:`~apf_physics.world.generate`: generated worlds for training and held-out tests.
"""

from apf_physics.world.core import FormationSpec, Frame, Moment, World

__all__ = ["FormationSpec", "Frame", "Moment", "World"]
