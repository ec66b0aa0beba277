"""Drawing: a state snapshot and the field's raster to an RGB ``uint8 (H, W, 3)`` frame.

Two steps, so that a video costs one background and many cheap frames:

- :meth:`FieldImage.from_world` renders, once per world and image size, everything that
  does not move: the potential as a log-scaled heatmap with level lines (thesis: purple),
  the obstacles (thesis: white) and the targets (red dots).
- :func:`draw_frame` copies that background and draws what a :class:`Snapshot` holds:
  each robot's trail and disc, and lines of overlay text. It is a pure function of its two
  arguments; no model object draws itself.

The text goes beside the map, never over it: by default in a band below the map, one row per
line (frames with text are taller than the map by the band; :func:`caption_height`), or, by
option (:attr:`FieldImage.caption`), over the map's top-left corner as before, or not at all.

Colours follow the thesis: a single robot is a blue disc with a yellow path (Fig. 1, 22,
23); in a formation the leader is yellow, follower 1 blue and follower 2 black (§6.4);
further followers get other distinct colours. Every disc and trail has a thin halo of a
contrasting colour, so it stays visible on any part of the heatmap.

World y is up, image rows go down: :class:`FieldImage` owns that flip and the scale
(pixels per world unit); nothing else converts coordinates.
"""

from __future__ import annotations

import re
import weakref
from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np

from apf_physics.world import field as apf
from apf_physics.world.obstacles import GridObstacle, obstacle_at
from apf_physics.world.core import World

RGB = tuple[int, int, int]

BLUE: RGB = (30, 90, 235)
YELLOW: RGB = (255, 210, 0)
BLACK: RGB = (0, 0, 0)
RED: RGB = (225, 25, 25)
WHITE: RGB = (255, 255, 255)
LEVEL_LINE: RGB = (120, 40, 150)       # thesis Fig. 22–23: level lines in purple
OBSTACLE_FILL: RGB = (250, 250, 250)   # thesis: obstacles are white
OBSTACLE_EDGE: RGB = (70, 70, 70)
ROUTE: RGB = (150, 150, 150)           # the faint line a moving obstacle travels along
DARK_HALO: RGB = (25, 25, 25)
LIGHT_HALO: RGB = (245, 245, 245)

#: Followers beyond the second, in order (follower3, follower4, ...).
EXTRA_FOLLOWER_COLOURS: tuple[RGB, ...] = (
    (0, 160, 70),     # green
    (215, 0, 200),    # magenta
    (255, 120, 0),    # orange
    (0, 185, 205),    # cyan
    (140, 80, 30),    # brown
    (130, 130, 130),  # grey
)

#: Colour families of the formations after the first (which keeps the thesis's yellow, blue,
#: black): per family, the leader's colour and its followers' (darker, then lighter shades).
FAMILIES: tuple[tuple[RGB, ...], ...] = (
    ((0, 160, 70), (0, 100, 40), (120, 210, 140), (0, 60, 25)),          # greens
    ((215, 0, 200), (130, 0, 120), (240, 120, 230), (80, 0, 75)),        # magentas
    ((255, 120, 0), (170, 70, 0), (255, 185, 120), (110, 45, 0)),        # oranges
    ((0, 185, 205), (0, 110, 125), (120, 225, 235), (0, 70, 80)),        # cyans
    ((140, 80, 30), (90, 50, 15), (200, 150, 100), (55, 30, 10)),        # browns
)

ROLES = ("single", "leader", "follower1", "follower2", "follower")
_ROLE_PATTERN = re.compile(r"^(single|leader|follower\d*)$")

SHADE_SAMPLES = 101        # points of the shade → potential table (the colour bar's scale)

CAPTIONS = ("below", "over", "off")
"""Where a frame's text goes (:attr:`FieldImage.caption`): in a band below the map (the default: it
never hides the map), over the map's top-left corner, or nowhere."""
CAPTION_BAND: RGB = (32, 32, 32)
FLOOR: RGB = (40, 44, 52)              # a map drawn without its field (a fleet's): dark floor, white obstacles

_SHIFT = 4                 # fractional bits for cv2 drawing: sub-pixel positions, smooth motion
_ONE = 1 << _SHIFT
_FONT = cv2.FONT_HERSHEY_SIMPLEX


def formation_roles(robots: int) -> tuple[str, ...]:
    """Roles of a formation of ``robots`` robots: the leader, then ``follower1``, ``follower2``, ...

    Args:
        robots: Number of robots, leader included (at least 1).
    """
    return ("leader",) + tuple(f"follower{i}" for i in range(1, robots))


def robot_colours(roles: Sequence[str], families: Sequence[int] = ()) -> list[tuple[RGB, RGB]]:
    """``(disc colour, trail colour)`` of each robot, by role (and formation).

    ``"single"`` is a blue disc with a yellow trail. In a formation each robot's trail has its
    disc's colour: leader yellow, follower1 blue, follower2 black, follower3+ from
    :data:`EXTRA_FOLLOWER_COLOURS`; plain ``"follower"`` robots take the next unused colour of
    that palette in order. With ``families`` (one formation number per robot), formations
    after the first take a colour family of :data:`FAMILIES` each: the leader its main colour,
    its followers shades of it.

    Raises:
        ValueError: for an unknown role.
    """
    out: list[tuple[RGB, RGB]] = []
    plain = 0
    for k, role in enumerate(roles):
        family = int(families[k]) if k < len(families) else 0
        if family > 0 and _ROLE_PATTERN.match(role) and role != "single":
            shades = FAMILIES[(family - 1) % len(FAMILIES)]
            rank = 0 if role == "leader" else int(role[len("follower"):] or 1) if role != "follower" else 1
            colour = shades[min(rank, len(shades) - 1)]
            out.append((colour, colour))
            continue
        if not _ROLE_PATTERN.match(role):
            raise ValueError(f"unknown robot role {role!r} (expected one of {', '.join(ROLES)}, or followerN)")
        if role == "single":
            out.append((BLUE, YELLOW))
            continue
        if role == "leader":
            colour = YELLOW
        elif role == "follower1":
            colour = BLUE
        elif role == "follower2":
            colour = BLACK
        elif role == "follower":
            colour = EXTRA_FOLLOWER_COLOURS[plain % len(EXTRA_FOLLOWER_COLOURS)]
            plain += 1
        else:
            number = int(role[len("follower"):])
            if number < 1:
                raise ValueError(f"unknown robot role {role!r} (followers are numbered from 1)")
            colour = EXTRA_FOLLOWER_COLOURS[(number - 3) % len(EXTRA_FOLLOWER_COLOURS)]
        out.append((colour, colour))
    return out


def _halo(colour: RGB) -> RGB:
    """A contrasting outline colour: light around dark colours, dark around the rest."""
    luminance = 0.299 * colour[0] + 0.587 * colour[1] + 0.114 * colour[2]
    return LIGHT_HALO if luminance < 60 else DARK_HALO


@dataclass(frozen=True, eq=False)
class Snapshot:
    """What one frame shows: the robots now, where they have been, and a few lines of text.

    Attributes:
        positions: ``(R, 2)`` robot centres in world coordinates.
        roles: One role per robot: ``"single"``, ``"leader"``, ``"follower1"``,
            ``"follower2"``, ``"followerN"`` or ``"follower"``.
        trails: Per robot, the ``(n_i, 2)`` points it has visited (oldest first), or empty
            for no trails at all.
        overlay: Lines of text drawn beside the map (:attr:`FieldImage.caption`), e.g.
            ``"step 12/40"``, ``"planner gradient"``, ``"outcome success"``.
        t: The control step shown: where the world's moving obstacles are drawn.
        families: One formation number per robot (several formations: each in a colour
            family of its own), or empty.
        headings: ``(R,)`` each robot's heading [rad] (unicycles: drawn as a line from the
            centre to the rim), or None (holonomic robots have none).
    """

    positions: np.ndarray
    roles: tuple[str, ...]
    trails: tuple[np.ndarray, ...] = ()
    overlay: tuple[str, ...] = ()
    t: float = 0.0
    families: tuple[int, ...] = ()
    headings: np.ndarray | None = None

    def __post_init__(self) -> None:
        positions = np.asarray(self.positions, dtype=float).reshape(-1, 2)
        object.__setattr__(self, "positions", positions)
        object.__setattr__(self, "roles", tuple(self.roles))
        object.__setattr__(self, "trails", tuple(np.asarray(t, dtype=float).reshape(-1, 2) for t in self.trails))
        object.__setattr__(self, "overlay", tuple(str(line) for line in self.overlay))
        if len(self.roles) != len(positions):
            raise ValueError(f"{len(positions)} robot positions but {len(self.roles)} roles")
        if self.trails and len(self.trails) != len(positions):
            raise ValueError(f"{len(positions)} robot positions but {len(self.trails)} trails")
        robot_colours(self.roles, self.families)  # validates the roles
        if self.headings is not None:
            headings = np.asarray(self.headings, dtype=float).reshape(-1)
            if len(headings) != len(positions):
                raise ValueError(f"{len(positions)} robot positions but {len(headings)} headings")
            object.__setattr__(self, "headings", headings)


@dataclass(frozen=True, eq=False)
class FieldImage:
    """The static part of every frame of one world at one image size, and the world↔pixel mapping.

    Build it with :meth:`from_world` (or the cached :func:`field_image`), once per world and size.

    Attributes:
        background: ``(H, W, 3)`` uint8 RGB, read-only: heatmap, level lines, obstacles, targets.
        scale: Pixels per world unit.
        world_size: ``(width, height)`` of the world in world units.
        robot_radius: Radius of a robot's disc in pixels (the true radius, at least ``min_radius``).
        line_width: Width of trails and paths in pixels.
        halo_width: Extra outline width around discs and trails in pixels.
        font_scale: OpenCV font scale of the overlay text.
        targets: ``(T, 2)`` target positions in world coordinates, redrawn over trails.
        target_radius: Radius of a target's dot in pixels.
        scaling: How the potential maps to colour: ``"log"`` or ``"rank"``.
        shade_potential: ``(SHADE_SAMPLES,)`` the potential U at shades ``0, 1/(n-1), ..., 1``
            of the heatmap (increasing; the last is where the colour scale saturates): the
            colour bar's scale.
        levels: Number of bands between level lines.
        moving: The world's moving obstacles, drawn on every frame where the snapshot's step
            puts them (empty when they are drawn into the background at one step).
        obstacle_px: Smallest radius of a drawn point obstacle in pixels.
        caption: Where frames' text goes (:data:`CAPTIONS`): ``"below"`` the map in a band of
            its own, ``"over"`` the map's top-left corner, or ``"off"``.
    """

    background: np.ndarray
    scale: float
    world_size: tuple[float, float]
    robot_radius: float
    line_width: int
    halo_width: int
    font_scale: float
    targets: np.ndarray
    target_radius: float
    scaling: str
    shade_potential: np.ndarray
    levels: int
    moving: tuple = ()
    obstacle_px: float = 3.0
    caption: str = "below"

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(H, W, 3)`` of the map (a frame with text below it is :func:`caption_height` taller)."""
        return self.background.shape  # type: ignore[return-value]

    @classmethod
    def from_world(
        cls,
        world: World,
        long_side: int = 512,
        *,
        raster_resolution: int | None = None,
        levels: int = 18,
        scaling: str = "log",
        min_radius: float = 3.0,
        t: float | None = None,
        caption: str = "below",
        field: bool = True,
    ) -> FieldImage:
        """Render the world's static picture.

        Args:
            world: The world.
            long_side: Pixels along the world's longer side; the other side keeps the aspect
                ratio. Pixels per unit are ``long_side / max(width, height)``, so a 50×50
                world at 512 px has about 10 px per unit.
            raster_resolution: Nodes per unit of the potential raster (``world.raster``).
                Default: a node every 2 pixels or so (4 to 16 per unit), fine enough that
                the thin plateau of the capped repulsion around obstacles is not jagged.
            levels: Number of bands the scaled potential is cut into; their edges are the
                level lines.
            scaling: How U maps to colour: ``"log"`` (default) or ``"rank"`` (histogram
                equalised: shows the basins of local minima most clearly).
            min_radius: Smallest disc radius in pixels, so robots and targets stay visible
                on large maps.
            t: For a world with moving obstacles: None, the background holds the static
                field and obstacles and the moving obstacles' routes as faint lines (the
                obstacles are drawn on each frame at the frame's step); a step, the field and
                every obstacle as they are at that step.
            caption: Where frames' text goes: ``"below"`` (default), ``"over"`` or ``"off"``
                (:data:`CAPTIONS`).
            field: False: the map alone, obstacles on a plain floor, no field and no targets (a
                fleet's video: each robot's goal is drawn in its own colour).
        """
        if long_side < 16:
            raise ValueError(f"long_side must be at least 16 pixels, got {long_side}")
        if caption not in CAPTIONS:
            raise ValueError(f"caption must be one of {', '.join(CAPTIONS)}, got {caption!r}")
        width, height = (float(world.size[0]), float(world.size[1]))
        scale = long_side / max(width, height)
        cols, rows = max(1, round(width * scale)), max(1, round(height * scale))
        unit = long_side / 512.0                      # line widths and text grow with the image
        line_width = max(2, round(2 * unit))
        halo_width = max(1, round(unit))
        min_px = max(min_radius, 3.0 * unit)
        if raster_resolution is None:
            raster_resolution = int(np.clip(np.ceil(scale / 2), 4, 16))
        shown = world.obstacles_at(t) if t is not None else world.static_obstacles
        if not field:
            return cls._plain(world, scale, rows, cols, unit, line_width, halo_width, min_px, shown, caption)
        raster = world.raster(raster_resolution)
        if world.moving:   # the field as the frames show it: at step t, or of the static obstacles
            grid = raster.grid
            nodes = grid.node_points()
            values = apf.potential(nodes, world.targets, shown, world.field, world.robot_radius)
            raster = apf.Raster(grid, values.reshape(grid.shape))

        shade, shade_potential = _shade(raster, world, scale, rows, cols, scaling, shown)
        shade_potential.setflags(write=False)
        image = heatmap(shade)
        draw_level_lines(image, shade, levels, thickness=max(1, round(unit)))

        image_cv = np.ascontiguousarray(image)
        robot_px = max(world.robot_radius * scale, min_px)
        targets = np.array(world.targets, dtype=float).reshape(-1, 2)
        targets.setflags(write=False)
        moving = tuple(world.obstacles[i] for i in world.moving) if t is None else ()
        mapping = cls(image_cv, scale, (width, height), robot_px, line_width, halo_width, 0.45 * unit,
                      targets, robot_px, scaling, shade_potential, levels, moving, min_px, caption)
        for obstacle in moving:
            mapping._draw_route(image_cv, obstacle)
        mapping._draw_obstacles(image_cv, shown, min_px)
        mapping._draw_tolerance(image_cv, world.goal_tolerance)
        mapping.draw_targets(image_cv)
        image_cv.setflags(write=False)
        return mapping

    @classmethod
    def _plain(cls, world: World, scale: float, rows: int, cols: int, unit: float, line_width: int, halo_width: int,
               min_px: float, shown: Sequence, caption: str) -> FieldImage:
        """The map alone: obstacles on a plain floor (see :meth:`from_world`'s ``field``)."""
        image = np.empty((rows, cols, 3), np.uint8)
        image[...] = FLOOR
        robot_px = max(world.robot_radius * scale, min(min_px, 0.4 * scale))
        targets = np.zeros((0, 2))
        targets.setflags(write=False)
        mapping = cls(image, scale, (float(world.size[0]), float(world.size[1])), robot_px, line_width, halo_width,
                      0.45 * unit, targets, robot_px, "log", np.zeros(SHADE_SAMPLES), 0, (), min_px, caption)
        mapping._draw_obstacles(image, shown, min_px)
        image.setflags(write=False)
        return mapping

    # -- world ↔ pixels ----------------------------------------------------------------
    def to_pixels(self, points: np.ndarray) -> np.ndarray:
        """Continuous image coordinates ``(x right, y down)`` of world points, ``(N, 2)`` float.

        Pixel ``(col, row)`` covers ``[col, col + 1) × [row, row + 1)`` in these coordinates.
        """
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        return np.column_stack([points[:, 0] * self.scale, (self.world_size[1] - points[:, 1]) * self.scale])

    def pixel_of(self, points: np.ndarray) -> np.ndarray:
        """``(col, row)`` integer index of the pixel each world point falls in, ``(N, 2)``."""
        h, w = self.background.shape[:2]
        px = np.floor(self.to_pixels(points)).astype(np.intp)
        return np.column_stack([np.clip(px[:, 0], 0, w - 1), np.clip(px[:, 1], 0, h - 1)])

    def _fixed(self, points: np.ndarray) -> np.ndarray:
        """cv2 fixed-point coordinates (``_SHIFT`` fractional bits) of world points, int32 ``(N, 2)``.

        cv2 puts integer coordinate ``c`` at the centre of pixel ``c``, hence the half-pixel shift.
        """
        return np.round((self.to_pixels(points) - 0.5) * _ONE).astype(np.int32)

    # -- static layers -----------------------------------------------------------------
    def _draw_obstacles(self, image: np.ndarray, obstacles: Sequence, min_px: float) -> None:
        edge = max(1, self.halo_width)
        for obstacle in obstacles:
            if isinstance(obstacle, GridObstacle):   # its cells, as the boxes that tile them, filled without edges
                boxes = obstacle.rectangles()
                corners = np.stack([boxes[:, [0, 1]], boxes[:, [2, 1]], boxes[:, [2, 3]], boxes[:, [0, 3]]], axis=1)
                pts = self._fixed(corners.reshape(-1, 2)).reshape(-1, 4, 2)
                cv2.fillPoly(image, list(pts), OBSTACLE_FILL, cv2.LINE_AA, _SHIFT)
            elif hasattr(obstacle, "vertices"):
                pts = self._fixed(obstacle.vertices)
                cv2.fillPoly(image, [pts], OBSTACLE_FILL, cv2.LINE_AA, _SHIFT)
                cv2.polylines(image, [pts], True, OBSTACLE_EDGE, edge, cv2.LINE_AA, _SHIFT)
            else:
                centre = tuple(self._fixed(obstacle.center)[0])
                # A point obstacle (radius 0) is drawn as a small dot so that it can be seen.
                radius = max(float(obstacle.radius) * self.scale, 0.8 * min_px)
                r = int(round(radius * _ONE))
                cv2.circle(image, centre, r, OBSTACLE_FILL, -1, cv2.LINE_AA, _SHIFT)
                cv2.circle(image, centre, r, OBSTACLE_EDGE, edge, cv2.LINE_AA, _SHIFT)

    def _draw_route(self, image: np.ndarray, obstacle) -> None:
        """The faint polyline a moving obstacle's centre travels along."""
        lo, hi = obstacle.bounds
        route = obstacle.motion.offset(np.linspace(0.0, obstacle.motion.period / obstacle.motion.speed, 400))
        pts = self._fixed((lo + hi) / 2 + route)
        cv2.polylines(image, [pts], False, ROUTE, 1, cv2.LINE_AA, _SHIFT)

    def draw_moving(self, image: np.ndarray, t: float) -> None:
        """Draw the moving obstacles where they are at step ``t`` onto ``image`` in place."""
        if self.moving:
            self._draw_obstacles(image, [obstacle_at(o, t) for o in self.moving], self.obstacle_px)

    def _draw_tolerance(self, image: np.ndarray, tolerance: float) -> None:
        # A robot whose centre is inside this ring has arrived.
        ring = tolerance * self.scale
        if ring > self.target_radius + 1:
            for centre in self._fixed(self.targets):
                cv2.circle(image, (int(centre[0]), int(centre[1])), int(round(ring * _ONE)), RED, 1,
                           cv2.LINE_AA, _SHIFT)

    # -- per-frame layers --------------------------------------------------------------
    def draw_targets(self, image: np.ndarray) -> None:
        """Draw the targets' red dots onto ``image`` in place (again over trails that end on them)."""
        r, halo = int(round(self.target_radius * _ONE)), int(round((self.target_radius + self.halo_width) * _ONE))
        for centre in self._fixed(self.targets):
            c = (int(centre[0]), int(centre[1]))
            cv2.circle(image, c, halo, DARK_HALO, -1, cv2.LINE_AA, _SHIFT)
            cv2.circle(image, c, r, RED, -1, cv2.LINE_AA, _SHIFT)

    def draw_path(self, image: np.ndarray, path: np.ndarray, colour: RGB, width: int | None = None) -> None:
        """Draw a polyline through world points onto ``image`` in place, with a contrasting halo."""
        if len(path) < 2:
            return
        width = self.line_width if width is None else width
        pts = self._fixed(path)
        if len(pts) > 2:
            # Thick anti-aliased polylines cost per vertex; dropping the vertices that lie within
            # a quarter pixel of the simplified line is invisible and cuts the cost 2-5 times.
            pts = cv2.approxPolyDP(pts.reshape(-1, 1, 2), _ONE // 4, False)
        cv2.polylines(image, [pts], False, _halo(colour), width + 2 * self.halo_width, cv2.LINE_AA, _SHIFT)
        cv2.polylines(image, [pts], False, colour, width, cv2.LINE_AA, _SHIFT)

    def draw_segment(self, image: np.ndarray, segment: np.ndarray, colour: RGB,
                     previous: np.ndarray | None = None) -> None:
        """Draw one trail segment (2, 2) in world points onto ``image`` in place, with its halo.

        The halo's round cap spills onto the end of the ``previous`` segment, so that one's
        colour is drawn again on top: joints look like one polyline's.
        """
        pts = self._fixed(segment)
        width = self.line_width
        cv2.line(image, tuple(map(int, pts[0])), tuple(map(int, pts[1])), _halo(colour),
                 width + 2 * self.halo_width, cv2.LINE_AA, _SHIFT)
        if previous is not None:
            prev = self._fixed(previous)
            cv2.line(image, tuple(map(int, prev[0])), tuple(map(int, prev[1])), colour, width, cv2.LINE_AA, _SHIFT)
        cv2.line(image, tuple(map(int, pts[0])), tuple(map(int, pts[1])), colour, width, cv2.LINE_AA, _SHIFT)

    def draw_disc(self, image: np.ndarray, centre: np.ndarray, colour: RGB, radius: float | None = None,
                  filled: bool = True) -> None:
        """Draw a robot-sized disc (or ring) at a world point onto ``image`` in place, with a halo."""
        radius = self.robot_radius if radius is None else radius
        c = tuple(int(v) for v in self._fixed(centre)[0])
        r = int(round(radius * _ONE))
        if filled:
            cv2.circle(image, c, r + self.halo_width * _ONE, _halo(colour), -1, cv2.LINE_AA, _SHIFT)
            cv2.circle(image, c, r, colour, -1, cv2.LINE_AA, _SHIFT)
        else:
            ring = max(2, self.line_width)
            cv2.circle(image, c, r, _halo(colour), ring + 2 * self.halo_width, cv2.LINE_AA, _SHIFT)
            cv2.circle(image, c, r, colour, ring, cv2.LINE_AA, _SHIFT)

    def draw_headings(self, image: np.ndarray, centres: np.ndarray, headings: np.ndarray) -> None:
        """Draw each robot's heading onto ``image`` in place: a dark line from its centre to the rim
        of its disc as drawn (``robot_radius`` is in pixels: the tip is that far in world units)."""
        reach = self.robot_radius / self.scale
        tips = centres + reach * np.column_stack([np.cos(headings), np.sin(headings)])
        for a, b in zip(self._fixed(centres), self._fixed(tips)):
            cv2.line(image, tuple(int(v) for v in a), tuple(int(v) for v in b), (20, 20, 20),
                     max(1, self.line_width), cv2.LINE_AA, _SHIFT)

    def draw_text(self, image: np.ndarray, lines: Sequence[str]) -> np.ndarray:
        """``image`` with lines of text where :attr:`caption` puts them: a new array with a band of
        the lines below the map (``"below"``), or ``image`` itself with the lines written in its
        top-left corner, white on a dimmed box (``"over"``), or untouched (``"off"``)."""
        if not lines or self.caption == "off":
            return image
        thickness = max(1, round(self.font_scale / 0.45))
        line_height, pad = _line_height(self.font_scale, thickness), 4 * thickness
        if self.caption == "below":
            band = np.empty((caption_height(self, len(lines)), image.shape[1], 3), np.uint8)
            band[...] = CAPTION_BAND
            for i, line in enumerate(lines):
                width = cv2.getTextSize(line, _FONT, self.font_scale, thickness)[0][0]
                # a line wider than the band is written smaller rather than cut
                scale = self.font_scale * min(1.0, (image.shape[1] - 2 * pad) / max(width, 1))
                y = pad + (i + 1) * line_height - line_height // 3
                cv2.putText(band, line, (pad, y), _FONT, scale, WHITE, thickness, cv2.LINE_AA)
            return np.concatenate([image, band])
        sizes = [cv2.getTextSize(line, _FONT, self.font_scale, thickness) for line in lines]
        box_w = min(image.shape[1], max(w for (w, _), _ in sizes) + 2 * pad)
        box_h = min(image.shape[0], line_height * len(lines) + pad)
        # Darken the box so the text reads on any background (cheap: a small region only).
        region = image[:box_h, :box_w]
        region //= 2
        for i, line in enumerate(lines):
            y = pad + (i + 1) * line_height - line_height // 3
            cv2.putText(image, line, (pad, y), _FONT, self.font_scale, WHITE, thickness, cv2.LINE_AA)
        return image


def _line_height(font_scale: float, thickness: int) -> int:
    """Pixels from one line of text to the next (the tallest glyphs and their descent, and a gap)."""
    (_, height), base = cv2.getTextSize("Ag", _FONT, font_scale, thickness)
    return height + base + 3 * thickness


def caption_height(image: FieldImage, lines: int) -> int:
    """Rows of the band below the map that holds ``lines`` lines of text (an even number, as video
    encoders want): what a frame with that many lines adds to :attr:`FieldImage.shape`; 0 when
    the text goes over the map or nowhere."""
    if lines <= 0 or image.caption != "below":
        return 0
    thickness = max(1, round(image.font_scale / 0.45))
    rows = _line_height(image.font_scale, thickness) * lines + 4 * thickness
    return rows + rows % 2


def _shade(raster, world: World, scale: float, rows: int, cols: int,
           scaling: str, obstacles: Sequence) -> tuple[np.ndarray, np.ndarray]:
    """The potential mapped monotonically to [0, 1] at every pixel centre, ``(rows, cols)`` float32,
    and the inverse map: U at :data:`SHADE_SAMPLES` evenly spaced shades, ``(SHADE_SAMPLES,)``.

    ``"log"``: ``log(1 + (U − U_min)/s)`` with ``s`` a fifth of the median of ``U − U_min``
    over free space, normalised by its 99th percentile there. The log compresses the steep
    walls of the repulsive terms and the far corners of the attractive bowl, so that the
    black holes around the targets and the basins of local minima stay visible.
    ``"rank"``: the fraction of free-space nodes with a lower potential (histogram
    equalisation); every shade covers the same area. Either way, level lines of the shade
    are level lines of U.
    """
    values = raster.values
    free = ~_obstacle_mask(obstacles, raster.grid)
    reference = values[free] if free.any() else values.ravel()
    samples = np.linspace(0.0, 1.0, SHADE_SAMPLES)
    if scaling == "rank":
        ordered = np.sort(reference)
        shade = np.searchsorted(ordered, values, side="right") / len(ordered)
        potential = np.quantile(ordered, samples)
    elif scaling == "log":
        lowest = float(values.min())
        lifted = values - lowest
        spread = max(float(np.median(lifted[free] if free.any() else lifted)), 1e-9)
        logged = np.log1p(lifted / (0.2 * spread))
        top = float(np.percentile(logged[free] if free.any() else logged, 99))
        shade = logged / top if top > 0 else np.zeros_like(logged)
        potential = lowest + 0.2 * spread * np.expm1(samples * top)
    else:
        raise ValueError(f"scaling must be 'log' or 'rank', got {scaling!r}")
    shade = np.clip(shade, 0.0, 1.0).astype(np.float32)
    # Pixel centres in world coordinates; the raster's grid turns them into node indices.
    xs = (np.arange(cols) + 0.5) / scale
    ys = world.size[1] - (np.arange(rows) + 0.5) / scale
    gx, gy = np.meshgrid(xs, ys)
    index = raster.grid.to_index(np.column_stack([gx.ravel(), gy.ravel()])).astype(np.float32)
    map_x = np.ascontiguousarray(index[:, 0].reshape(rows, cols))
    map_y = np.ascontiguousarray(index[:, 1].reshape(rows, cols))
    return cv2.remap(shade, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE), potential


def _obstacle_mask(obstacles: Sequence, grid) -> np.ndarray:
    """True at the raster nodes inside one of ``obstacles``, ``(rows, cols)`` bool.

    Filled with cv2 in grid-index space (exact to a node): the colour scale's statistics need
    only the free nodes, and measuring distances at every node would cost a hundred times more.
    """
    mask = np.zeros(grid.shape, dtype=np.uint8)
    for obstacle in obstacles:
        if isinstance(obstacle, GridObstacle):
            boxes = obstacle.rectangles()
            corners = np.stack([boxes[:, [0, 1]], boxes[:, [2, 1]], boxes[:, [2, 3]], boxes[:, [0, 3]]], axis=1)
            pts = np.round(grid.to_index(corners.reshape(-1, 2)) * _ONE).astype(np.int32).reshape(-1, 4, 2)
            cv2.fillPoly(mask, list(pts), 1, cv2.LINE_8, _SHIFT)
        elif hasattr(obstacle, "vertices"):
            pts = np.round(grid.to_index(obstacle.vertices) * _ONE).astype(np.int32)
            cv2.fillPoly(mask, [pts], 1, cv2.LINE_8, _SHIFT)
        elif obstacle.radius > 0:
            centre = np.round(grid.to_index(obstacle.center[None]) * _ONE).astype(np.int32)[0]
            radius = int(round(obstacle.radius * grid.resolution * _ONE))
            cv2.circle(mask, (int(centre[0]), int(centre[1])), radius, 1, -1, cv2.LINE_8, _SHIFT)
    return mask.astype(bool)


def heatmap(shade: np.ndarray) -> np.ndarray:
    """RGB heatmap of a [0, 1] shade: a colour map washed towards white so robots stand out."""
    grey = np.clip(shade * 255.0, 0, 255).astype(np.uint8)
    bgr = cv2.applyColorMap(grey, cv2.COLORMAP_VIRIDIS)
    rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    # 45 % colour map, 55 % white: a pale heatmap, on which blue, yellow, black and red read.
    return cv2.addWeighted(rgb, 0.45, np.full_like(rgb, 255), 0.55, 0.0)


def draw_level_lines(image: np.ndarray, shade: np.ndarray, levels: int, thickness: int) -> None:
    """Mark the edges between bands of equal quantised shade (level lines of log U), in place.

    Band edges rather than ``cv2.findContours`` per level: the same lines, without spurious
    contours along the image border. A light blur anti-aliases them.
    """
    band = np.minimum((shade * levels).astype(np.int32), levels - 1)
    edge = np.zeros(band.shape, dtype=np.uint8)
    edge[:, 1:] |= (band[:, 1:] != band[:, :-1])
    edge[1:, :] |= (band[1:, :] != band[:-1, :])
    if thickness > 1:
        edge = cv2.dilate(edge, np.ones((thickness, thickness), np.uint8))
    alpha = cv2.GaussianBlur(edge.astype(np.float32), (3, 3), 0.6) * 0.85
    alpha = alpha[:, :, None]
    blended = image * (1.0 - alpha) + np.asarray(LEVEL_LINE, np.float32) * alpha
    image[...] = np.clip(blended + 0.5, 0, 255).astype(np.uint8)


def draw_frame(field_image: FieldImage, snapshot: Snapshot) -> np.ndarray:
    """One frame: the field's background with the snapshot's trails, robots and overlay text.

    Args:
        field_image: The world's static picture (see :meth:`FieldImage.from_world`).
        snapshot: The robots and text to show.

    Returns:
        A new ``(H, W, 3)`` uint8 RGB array; neither argument is modified.
    """
    frame = field_image.background.copy()
    field_image.draw_moving(frame, snapshot.t)
    colours = robot_colours(snapshot.roles, snapshot.families)
    for trail, (_, trail_colour) in zip(snapshot.trails, colours):
        field_image.draw_path(frame, trail, trail_colour)
    return _draw_robots(frame, field_image, snapshot, colours)


def _draw_robots(frame: np.ndarray, field_image: FieldImage, snapshot: Snapshot, colours) -> np.ndarray:
    # Targets again on top of the trails that end on them, then the robots, then the text.
    field_image.draw_targets(frame)
    for position, (disc_colour, _) in zip(snapshot.positions, colours):
        field_image.draw_disc(frame, position, disc_colour)
    if snapshot.headings is not None:
        field_image.draw_headings(frame, snapshot.positions, snapshot.headings)
    return field_image.draw_text(frame, snapshot.overlay)


class TrailLayer:
    """The background with the trails so far, grown by one segment per robot and step (for videos).

    :func:`draw_frame` redraws every trail on every frame, which costs time in proportion to
    the trails' length; a video of a long episode instead grows this layer step by step and
    draws only the robots and text over a copy of it, at the same cost at every step. The
    frames look the same as :func:`draw_frame`'s up to anti-aliasing at the joints.

    Args:
        field_image: The world's static picture.
        roles: One role per robot (they fix the trail colours).
        families: One formation number per robot (see :func:`robot_colours`), or empty.
    """

    def __init__(self, field_image: FieldImage, roles: Sequence[str], families: Sequence[int] = ()):
        self.field_image = field_image
        self.colours = robot_colours(roles, families)
        self.canvas = field_image.background.copy()
        self._last: np.ndarray | None = None
        self._previous: list[np.ndarray | None] = [None] * len(self.colours)

    def extend(self, positions: np.ndarray) -> None:
        """Add the segment from each robot's previous position to ``positions`` (R, 2)."""
        positions = np.asarray(positions, dtype=float).reshape(-1, 2)
        if len(positions) != len(self.colours):
            raise ValueError(f"{len(positions)} positions for {len(self.colours)} robots")
        if self._last is not None:
            for i, (start, end) in enumerate(zip(self._last, positions)):
                if np.array_equal(start, end):
                    continue
                segment = np.stack([start, end])
                self.field_image.draw_segment(self.canvas, segment, self.colours[i][1], self._previous[i])
                self._previous[i] = segment
        self._last = positions.copy()

    def frame(self, snapshot: Snapshot) -> np.ndarray:
        """A new frame: this layer's trails (not the snapshot's), the snapshot's robots and text."""
        frame = self.canvas.copy()
        self.field_image.draw_moving(frame, snapshot.t)
        return _draw_robots(frame, self.field_image, snapshot, self.colours)


_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def field_image(world: World, long_side: int = 512, caption: str = "below") -> FieldImage:
    """The world's :class:`FieldImage` at ``long_side`` pixels, built on first use and cached per world."""
    per_world = _CACHE.setdefault(world, {})
    if (long_side, caption) not in per_world:
        per_world[(long_side, caption)] = FieldImage.from_world(world, long_side, caption=caption)
    return per_world[(long_side, caption)]
