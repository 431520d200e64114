"""The figure of a planned trajectory: obstacles, the leader's path, the footprint corridor.

``python -m formation.outputs.plan_figure SCENARIO OUT.png`` (or :func:`plot_plan`) draws a scenario
whose trajectory is ``kind = "plan"``: the arena and obstacles, the virtual leader's planned
path (black), every slot's path (dashed) and the slots' discs of the footprint (body, reference
offset, filter margin, planning clearance) every ``every_s`` seconds, coloured by the squeeze
(blue: nominal, through green: shrunk, to red: a column), over the footprint corridor they
sweep (translucent green, :mod:`formation.outputs.plan_view`). docs/planning.md shows the
built-in scenarios' figures made this way.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from coordinator.core.formation import FormationSpec, morphed_slot_rows, slot_rows
from coordinator.core.planning.feasibility import trajectory_of
from coordinator.core.planning.trajectory import PlannedTrajectory
from formation.outputs.plan_view import draw_plan, plan_view
from scenario.load import Scenario, load

__all__ = ["plot_plan"]


def plot_plan(scn: Scenario, path: Path, every_s: float = 2.0) -> None:
    """Draw ``scn``'s plan to ``path`` (PNG); raises ValueError if it does not plan."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle

    from formation.outputs.figures_style import draw_world

    traj = trajectory_of(scn.trajectory)
    if not isinstance(traj, PlannedTrajectory):
        raise ValueError(f"{scn.name}: the trajectory is not a plan")
    spec = FormationSpec.from_dict(dict(scn.formation))
    r = traj.result
    fig, ax = plt.subplots(figsize=(10, 6.5), dpi=90)
    draw_world(ax, scn.agent.world, scale=1.0)
    cmap = plt.get_cmap("turbo")
    radius = r.footprint.slot_radius_m
    ts = np.arange(0.0, traj.duration_s + every_s, every_s)
    dense = np.arange(0.0, traj.duration_s, 0.1)
    paths = np.empty((len(dense), len(spec), 2))
    for k, t in enumerate(dense):
        leader = traj.sample(float(t))
        offs = traj.slot_offsets(float(t))
        _, rows = slot_rows(spec, leader) if offs is None else morphed_slot_rows(leader, offs)
        paths[k] = [(row[0], row[1]) for row in rows]
    for j in range(len(spec)):
        ax.plot(paths[:, j, 0], paths[:, j, 1], "--", lw=0.8, color="0.45")
    for t in ts:
        leader = traj.sample(float(t))
        offs = traj.slot_offsets(float(t))
        q = 0.0
        if offs is not None:
            _, _, k, u = traj.where(float(t))
            q = float(r.q[k] + (r.q[k + 1] - r.q[k]) * u)
        _, rows = slot_rows(spec, leader) if offs is None else morphed_slot_rows(leader, offs)
        for row in rows:
            ax.add_patch(Circle((row[0], row[1]), radius, fc=cmap(q / 2.0), ec="none", alpha=0.18))
    view = plan_view(scn.trajectory, timed=False)
    if view is not None:  # the footprint corridor under the discs, as in every figure
        draw_plan(ax, view, scale=1.0)["path"].remove()
    ax.plot(r.x_m, r.y_m, "-", color="k", lw=1.5, label="planned leader path")
    ax.plot(*zip(*r.waypoints, strict=True), "o", ms=3, color="k")
    st = r.stats
    ax.set_title(
        f"{scn.name}: {len(spec)} slots, path {st.length_m:.2f} m (straight {st.straight_m:.2f} m),"
        f" to goal {st.duration_s:.0f} s, least slot clearance {st.min_clearance_m:.3f} m"
    )
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print("usage: python -m formation.outputs.plan_figure SCENARIO OUT.png", file=sys.stderr)
        return 2
    plot_plan(load(argv[0]), Path(argv[1]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
