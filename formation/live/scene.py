"""The 3D scene of a fleet for Foxglove (``/scene`` and ``/tf``), built from bus messages.

:class:`SceneModel` keeps the latest pose, slot, leader and assignment of a fleet and renders
``foxglove.SceneUpdate`` / ``foxglove.FrameTransforms`` messages: each robot as a cylinder with
a heading arrow and label, its reference point (eqs 10-11), every slot coloured by role, the
virtual leader, the leader-follower tree (eqs 3-5), each robot's tracking error vector
(eqs 17-18), the scenario's obstacles and arena (``world``, issue 14) and a planned
trajectory's leader path and footprint corridor (``set_plan``, issue 27). The live server
(:mod:`formation.live.foxglove`) and the recorder (:mod:`formation.record.command`) both draw with
it, so a
recording looks like the live view.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Final

from foxglove.messages import (
    ArrowPrimitive,
    Color,
    CylinderPrimitive,
    FrameTransform,
    FrameTransforms,
    KeyValuePair,
    LinePrimitive,
    LinePrimitiveLineType,
    Point3,
    Pose,
    Quaternion,
    SceneEntity,
    SceneEntityDeletion,
    SceneEntityDeletionType,
    SceneUpdate,
    SpherePrimitive,
    TextPrimitive,
    Timestamp,
    TriangleListPrimitive,
    Vector3,
)

from bus_schemas import (
    Assignment,
    Leader,
    Message,
    PoseBatch,
    Slot,
    Status,
    TruthBatch,
    keys,
)
from bus_schemas import Pose as BusPose
from bus_schemas import Truth as BusTruth
from formation.outputs.bus_json import alive_kind
from robot_agent.core.kinematics import reference_point
from robot_agent.core.params import RobotGeometry

SCENE_TOPIC: Final = "/scene"
TF_TOPIC: Final = "/tf"
WORLD_FRAME: Final = "world"

ROBOT_HEIGHT_M: Final = 0.06
SLOT_DIAMETER_M: Final = 0.04
REF_DIAMETER_M: Final = 0.02
OBSTACLE_HEIGHT_M: Final = 0.1

_PALETTE: Final = [
    (0.84, 0.15, 0.16),
    (0.17, 0.63, 0.17),
    (0.12, 0.47, 0.71),
    (1.0, 0.5, 0.05),
    (0.58, 0.4, 0.74),
    (0.55, 0.34, 0.29),
    (0.89, 0.47, 0.76),
    (0.74, 0.74, 0.13),
    (0.09, 0.75, 0.81),
]  # matplotlib's tab10 without grey, like formation.outputs.figures
_ROLE_COLORS: Final = {
    "leader": (1.0, 0.78, 0.0),
    "subleader": (1.0, 0.45, 0.0),
    "follower": (0.3, 0.55, 0.95),
}
_DEAD: Final = (0.55, 0.55, 0.55)


def _color(rgb: tuple[float, float, float], a: float = 1.0) -> Color:
    return Color(r=rgb[0], g=rgb[1], b=rgb[2], a=a)


def _yaw(theta: float) -> Quaternion:
    """Rotation by ``theta`` (rad) about +z."""
    return Quaternion(x=0.0, y=0.0, z=math.sin(theta / 2.0), w=math.cos(theta / 2.0))


def _pose(x: float, y: float, z: float = 0.0, theta: float = 0.0) -> Pose:
    return Pose(position=Vector3(x=x, y=y, z=z), orientation=_yaw(theta))


def world_entity(world: Any, stamp: Timestamp) -> SceneEntity | None:
    """A ``WorldMap``'s obstacles (grey cylinders for discs, grey lines for segments and polygon
    edges) and its arena (a white outline) as one ``"world"`` entity; None if it has none."""
    if world is None or (not world.obstacles and world.arena is None):
        return None
    from robot_agent.core.params import CircleObstacle

    cylinders: list[CylinderPrimitive] = []
    walls: list[Point3] = []
    grey = _color((0.6, 0.6, 0.6), 0.9)
    for o in world.obstacles:
        if isinstance(o, CircleObstacle):
            d = 2.0 * o.radius_m
            cylinders.append(
                CylinderPrimitive(
                    pose=_pose(o.x, o.y, OBSTACLE_HEIGHT_M / 2.0),
                    size=Vector3(x=d, y=d, z=OBSTACLE_HEIGHT_M),
                    bottom_scale=1.0,
                    top_scale=1.0,
                    color=grey,
                )
            )
        else:
            walls += [Point3(x=o.x1, y=o.y1, z=0.02), Point3(x=o.x2, y=o.y2, z=0.02)]
    lines: list[LinePrimitive] = []
    if walls:
        lines.append(
            LinePrimitive(
                type=LinePrimitiveLineType.LineList,
                thickness=5.0,
                scale_invariant=True,
                points=walls,
                color=grey,
            )
        )
    a = world.arena
    if a is not None:
        corners = [(a.x_min, a.y_min), (a.x_max, a.y_min), (a.x_max, a.y_max), (a.x_min, a.y_max)]
        lines.append(
            LinePrimitive(
                type=LinePrimitiveLineType.LineLoop,
                thickness=2.0,
                scale_invariant=True,
                points=[Point3(x=x, y=y, z=0.0) for x, y in corners],
                color=_color((0.95, 0.95, 0.95), 0.8),
            )
        )
    return SceneEntity(
        timestamp=stamp, frame_id=WORLD_FRAME, id="world", cylinders=cylinders, lines=lines
    )


PLAN_ENTITY: Final = "plan"
_PLAN_RGB: Final = (0.2, 0.75, 0.35)
CORRIDOR_ALPHA: Final = 0.22
PLAN_PATH_Z_M: Final = 0.002
"""Height (m) of the planned path, just above the corridor (on the floor, ``z = 0``: a zero
coordinate costs nothing on the wire) and under the slots and robots."""
PLAN_REPEAT_S: Final = 1.0
"""The plan entity (10-20 kB for the built-in scenarios) is sent when it changes and then
once per this period (s), not with every scene: entities persist in the viewer until replaced,
and a viewer that connects later, or a seek in a recording, gets it within the period."""


@dataclass(frozen=True)
class PlanPrimitives:
    """A plan (``formation.outputs.plan_view.PlanMesh``) as Foxglove primitives, built once per
    plan (the scene is redrawn at ``scene_hz`` with the same objects): the planned leader path
    and the corridor's outline as lines, the corridor as a translucent triangle list, and a
    label per replan; ``revision`` counts the plans shown (1: the first)."""

    lines: tuple[LinePrimitive, ...]
    triangles: tuple[TriangleListPrimitive, ...]
    texts: tuple[TextPrimitive, ...]
    revision: int


def plan_primitives(mesh: Any, revision: int = 1) -> PlanPrimitives:
    """:class:`PlanPrimitives` of a ``PlanMesh`` (m)."""
    lines = [
        LinePrimitive(
            type=LinePrimitiveLineType.LineStrip,
            thickness=4.0,
            scale_invariant=True,
            points=[Point3(x=float(x), y=float(y), z=PLAN_PATH_Z_M) for x, y in mesh.path],
            color=_color(_PLAN_RGB, 0.95),
        )
    ]
    lines += [
        LinePrimitive(
            type=LinePrimitiveLineType.LineStrip,
            thickness=1.0,
            scale_invariant=True,
            points=[Point3(x=float(x), y=float(y), z=0.0) for x, y in ring],
            color=_color(_PLAN_RGB, 0.6),
        )
        for ring in mesh.outlines
    ]
    triangles = []
    if len(mesh.triangles):
        triangles.append(
            TriangleListPrimitive(
                pose=_pose(0.0, 0.0),
                points=[Point3(x=float(x), y=float(y), z=0.0) for x, y in mesh.vertices],
                color=_color(_PLAN_RGB, CORRIDOR_ALPHA),
                indices=[int(i) for i in mesh.triangles.reshape(-1)],
            )
        )
    texts = [
        TextPrimitive(
            pose=_pose(x, y, 0.1),
            billboard=True,
            font_size=12.0,
            scale_invariant=True,
            color=_color((1.0, 0.35, 0.3)),
            text=label,
        )
        for x, y, label in mesh.marks
    ]
    return PlanPrimitives(tuple(lines), tuple(triangles), tuple(texts), revision)


def _stamp(wall_ns: int) -> Timestamp:
    return Timestamp(wall_ns // 1_000_000_000, wall_ns % 1_000_000_000)


# --------------------------------------------------------------------------------------------
# Scene model (pure: bus messages in, Foxglove messages out)
# --------------------------------------------------------------------------------------------


@dataclass
class _Robot:
    xytheta: tuple[float, float, float] | None = None
    from_pose: bool = False
    alive: bool | None = None
    mode: str | None = None
    slot_status: int | None = None
    role: str | None = None


@dataclass
class SceneModel:
    """The fleet as last seen on the bus, turned into a ``SceneUpdate`` and ``FrameTransforms``.

    Feed decoded messages with :meth:`update` and liveliness with :meth:`set_alive`; no I/O, no
    clock (times are passed in). ``ref_offset_m`` is the reference point's distance ahead of
    the axle (eqs 10-11), ``body_radius_m`` the drawn body radius, both in m.
    """

    fleet: str = keys.DEFAULT_FLEET
    ref_offset_m: float = RobotGeometry().ref_offset_m
    body_radius_m: float = RobotGeometry().body_radius_m
    robots: dict[str, _Robot] = field(default_factory=dict)
    slots: dict[int, Slot] = field(default_factory=dict)
    assignment: dict[str, int] = field(default_factory=dict)
    leader: Leader | None = None
    world: Any = None  # robot_agent.core.params.WorldMap: obstacles and arena (issue 14), or None
    plan: PlanPrimitives | None = None  # the plan shown (issue 27): set_plan, never per tick
    _revision: int = 0
    _plan_gone: bool = False  # a plan was shown and removed: the next scene deletes it
    _plan_sent: tuple[int, int] | None = None  # (revision, wall ns) of the last plan sent

    def set_plan(self, mesh: Any) -> None:
        """Show the plan ``mesh`` (a ``formation.outputs.plan_view.PlanMesh``; None: no plan)
        from the next scene on: the ``"plan"`` entity is replaced (a new plan after a replan)
        or deleted. One attribute assignment: safe while another thread draws the scene."""
        self._revision += 1
        self._plan_gone = mesh is None and self.plan is not None
        self.plan = None if mesh is None else plan_primitives(mesh, self._revision)

    def _robot(self, rid: str) -> _Robot:
        r = self.robots.get(rid)
        if r is None:
            r = self.robots[rid] = _Robot()
        return r

    def _place(self, rid: str, xytheta: tuple[float, float, float], measured: bool) -> None:
        """Robot ``rid`` at ``xytheta``: a measured pose always, truth until a pose came."""
        r = self._robot(rid)
        if measured:
            r.xytheta, r.from_pose = xytheta, True
        elif not r.from_pose:
            r.xytheta = xytheta

    def update(self, key: str, msg: Message) -> None:
        """Take one decoded bus message of ``key``."""
        if isinstance(msg, Slot):
            self.slots[msg.slot] = msg
        elif isinstance(msg, Leader):
            self.leader = msg
        elif isinstance(msg, Assignment):
            self.assignment = dict(msg.robots)
        elif isinstance(msg, PoseBatch | TruthBatch):  # (a lockstep run's, agent hosts' frames)
            measured = isinstance(msg, PoseBatch)
            for rid, x, y, th in zip(msg.robots, msg.x, msg.y, msg.theta, strict=True):
                self._place(rid, (x, y, th), measured)
        else:
            parsed = keys.parse_robot_key(key)
            if parsed is None:
                return
            r = self._robot(parsed[1])
            if isinstance(msg, BusPose | BusTruth):
                self._place(parsed[1], (msg.x, msg.y, msg.theta), isinstance(msg, BusPose))
            elif isinstance(msg, Status):
                r.mode, r.slot_status, r.role = msg.mode, msg.slot, msg.role

    def set_alive(self, key: str, alive: bool) -> None:
        """A liveliness token appeared or vanished."""
        kind, ident = alive_kind(key)
        if kind == "robot" and ident is not None:
            self._robot(ident).alive = alive

    def _ordered(self) -> list[str]:
        return sorted(self.robots, key=lambda r: (len(r), r))

    def ref_point(self, rid: str) -> tuple[float, float] | None:
        """The robot's reference point (eqs 10-11) from its latest pose, m."""
        r = self.robots.get(rid)
        if r is None or r.xytheta is None:
            return None
        x, y, th = r.xytheta
        return reference_point(x, y, th, self.ref_offset_m)

    def scene(self, wall_ns: int) -> SceneUpdate:
        """The whole scene at ``wall_ns`` (ns since the epoch), replacing the previous one."""
        stamp = _stamp(wall_ns)
        entities: list[SceneEntity] = []

        def entity(ident: str, **prims: Any) -> SceneEntity:
            return SceneEntity(timestamp=stamp, frame_id=WORLD_FRAME, id=ident, **prims)

        rad = self.body_radius_m
        for n, rid in enumerate(self._ordered()):
            r = self.robots[rid]
            if r.xytheta is None:
                continue
            x, y, th = r.xytheta
            rgb = _PALETTE[n % len(_PALETTE)] if r.alive is not False else _DEAD
            slot = self.assignment.get(rid)
            slot_msg = self.slots.get(slot) if slot is not None else None
            role = slot_msg.role if slot_msg is not None else r.role
            label = rid
            if slot is not None:
                label += f"  v{slot + 1}" + (f" {role}" if role else "")
            if r.mode:
                label += f"  {r.mode}"
            if r.alive is False:
                label += "  (lost)"
            ref = self.ref_point(rid)
            spheres = []
            if ref is not None:
                spheres.append(
                    SpherePrimitive(
                        pose=_pose(ref[0], ref[1], ROBOT_HEIGHT_M),
                        size=Vector3(x=REF_DIAMETER_M, y=REF_DIAMETER_M, z=REF_DIAMETER_M),
                        color=_color(rgb),
                    )
                )
            entities.append(
                entity(
                    f"robot/{rid}",
                    cylinders=[
                        CylinderPrimitive(
                            pose=_pose(x, y, ROBOT_HEIGHT_M / 2.0, th),
                            size=Vector3(x=2 * rad, y=2 * rad, z=ROBOT_HEIGHT_M),
                            bottom_scale=1.0,
                            top_scale=1.0,
                            color=_color(rgb, 0.8),
                        )
                    ],
                    arrows=[
                        ArrowPrimitive(
                            pose=_pose(x, y, ROBOT_HEIGHT_M + 0.005, th),
                            shaft_length=rad,
                            shaft_diameter=0.01,
                            head_length=0.03,
                            head_diameter=0.03,
                            color=_color((0.1, 0.1, 0.1)),
                        )
                    ],
                    spheres=spheres,
                    texts=[
                        TextPrimitive(
                            pose=_pose(x, y, ROBOT_HEIGHT_M + 0.08),
                            billboard=True,
                            font_size=14.0,
                            scale_invariant=True,
                            color=_color((1.0, 1.0, 1.0)),
                            text=label,
                        )
                    ],
                )
            )
        slot_spheres: list[SpherePrimitive] = []
        slot_texts: list[TextPrimitive] = []
        tree: list[Point3] = []
        for k in sorted(self.slots):
            s = self.slots[k]
            d = SLOT_DIAMETER_M * (1.5 if k == 0 else 1.0)
            slot_spheres.append(
                SpherePrimitive(
                    pose=_pose(s.x, s.y, 0.01),
                    size=Vector3(x=d, y=d, z=d),
                    color=_color(_ROLE_COLORS.get(s.role, (0.7, 0.7, 0.7)), 0.9),
                )
            )
            slot_texts.append(
                TextPrimitive(
                    pose=_pose(s.x, s.y, 0.04),
                    billboard=True,
                    font_size=12.0,
                    scale_invariant=True,
                    color=_color((0.85, 0.85, 0.85)),
                    text=f"v{k + 1}",
                )
            )
            parent = self.slots.get(s.parent) if s.parent is not None else None
            if parent is not None:
                tree += [Point3(x=parent.x, y=parent.y, z=0.01), Point3(x=s.x, y=s.y, z=0.01)]
        lines: list[LinePrimitive] = []
        if tree:
            lines.append(
                LinePrimitive(
                    type=LinePrimitiveLineType.LineList,
                    thickness=2.0,
                    scale_invariant=True,
                    points=tree,
                    color=_color((0.8, 0.8, 0.8), 0.8),
                )
            )
        for n, rid in enumerate(self._ordered()):
            slot = self.assignment.get(rid)
            ref = self.ref_point(rid)
            target = self.slots.get(slot) if slot is not None else None
            if ref is None or target is None:
                continue
            lines.append(
                LinePrimitive(
                    type=LinePrimitiveLineType.LineList,
                    thickness=2.0,
                    scale_invariant=True,
                    points=[
                        Point3(x=ref[0], y=ref[1], z=ROBOT_HEIGHT_M),
                        Point3(x=target.x, y=target.y, z=0.01),
                    ],
                    color=_color(_PALETTE[n % len(_PALETTE)]),
                )
            )
        entities.append(entity("slots", spheres=slot_spheres, texts=slot_texts))
        entities.append(entity("links", lines=lines))
        if self.leader is not None:
            ld = self.leader
            entities.append(
                entity(
                    "virtual_leader",
                    arrows=[
                        ArrowPrimitive(
                            pose=_pose(ld.x, ld.y, 0.02, ld.theta),
                            shaft_length=0.08,
                            shaft_diameter=0.012,
                            head_length=0.04,
                            head_diameter=0.035,
                            color=_color((0.85, 0.2, 0.85)),
                        )
                    ],
                )
            )
        world = world_entity(self.world, stamp)
        if world is not None:
            entities.append(world)
        return self._with_plan(entities, stamp, wall_ns)

    def _with_plan(
        self, entities: list[SceneEntity], stamp: Timestamp, wall_ns: int
    ) -> SceneUpdate:
        """``entities`` and the plan entity when it is due (changed, or not sent for
        :data:`PLAN_REPEAT_S`), or its deletion once after the plan was removed."""
        plan = self.plan
        if plan is None:
            if not self._plan_gone:
                return SceneUpdate(entities=entities)
            self._plan_gone = False
            gone = SceneEntityDeletion(
                timestamp=stamp, type=SceneEntityDeletionType.MatchingId, id=PLAN_ENTITY
            )
            return SceneUpdate(deletions=[gone], entities=entities)
        if self._plan_sent is not None:
            revision, sent_ns = self._plan_sent
            if revision == plan.revision and 0 <= wall_ns - sent_ns < PLAN_REPEAT_S * 1e9:
                return SceneUpdate(entities=entities)  # the viewer still has it
        entities.append(
            SceneEntity(
                timestamp=stamp,
                frame_id=WORLD_FRAME,
                id=PLAN_ENTITY,
                lines=list(plan.lines),
                triangles=list(plan.triangles),
                texts=list(plan.texts),
                metadata=[KeyValuePair(key="revision", value=str(plan.revision))],
            )
        )
        self._plan_sent = (plan.revision, wall_ns)
        return SceneUpdate(entities=entities)

    def transforms(self, wall_ns: int) -> FrameTransforms:
        """``world`` -> ``<robot id>`` for every robot with a pose."""
        stamp = _stamp(wall_ns)
        out: list[FrameTransform] = []
        for rid in self._ordered():
            r = self.robots[rid]
            if r.xytheta is None:
                continue
            x, y, th = r.xytheta
            out.append(
                FrameTransform(
                    timestamp=stamp,
                    parent_frame_id=WORLD_FRAME,
                    child_frame_id=rid,
                    translation=Vector3(x=x, y=y, z=0.0),
                    rotation=_yaw(th),
                )
            )
        return FrameTransforms(transforms=out)
