#!/usr/bin/env python3
"""Where a hand's locked finger joints put its fingers, in the hand's grasp frame.

For each finger link of a hand (the collision hulls of the full URDF, finger joints kept) at the
robot config's ``locked_posture``: how far it reaches past the palm face along the grasp normal
(the plane the grasp cylinder touches), and whether it stands in the rung's corridor (within the
grasp radius of the grasp axis, beyond it: what a held rung meets as the hand backs off along the
normal). A hand backing off a rung along the palm normal clears it by (back-off - reach past the face)
of what stands beside the corridor.

``--search JOINT,...`` grid-searches those locked joints (``--step`` rad) for the posture with the
smallest reach past the face whose searched links all stay out of the corridor.

    .venv/bin/python scripts/hand_geometry.py --robot g1 --hand left_hand
    .venv/bin/python scripts/hand_geometry.py --hand left_hand \
        --search left_hand_thumb_0_joint,left_hand_thumb_1_joint,left_hand_thumb_2_joint

The last line is one JSON object: {"reach_past_face_m": ..., "corridor_clear": ..., "posture_rad": {...}}.
"""
from __future__ import annotations

import argparse
import itertools
import json
import sys

import numpy as np


def finger_points(robot, hand: str, posture: dict[str, float]) -> dict[str, np.ndarray]:
    """Hull vertices of every link below the hand's locked joints, in the grasp surface frame
    (x across the palm, y along the grasp normal from the palm face, z along the grasp axis)."""
    import pinocchio as pin

    full, geom = robot.full_model, robot.full_collision_model
    limb = robot.config.limbs[hand]
    q = pin.neutral(full)
    for name, value in {**robot.config.locked_posture, **posture}.items():
        q[full.joints[full.getJointId(name)].idx_q] = value
    data, gdata = full.createData(), pin.GeometryData(geom)
    pin.forwardKinematics(full, data, q)
    pin.updateFramePlacements(full, data)
    pin.updateGeometryPlacements(full, data, geom, gdata)
    surface = limb.surface
    axis, normal = np.asarray(surface.axis, float), np.asarray(surface.normal, float)
    across = np.cross(axis, normal)
    face = np.asarray(surface.centre, float) - surface.radius * normal  # a point of the palm face
    T_hand = data.oMf[full.getFrameId(surface.frame)].inverse()
    wrist = full.frames[full.getFrameId(surface.frame)].parentJoint

    def below_wrist(jid: int) -> bool:
        while jid > 0 and jid != wrist:
            jid = full.parents[jid]
        return jid == wrist

    subtree = {jid for jid in map(full.getJointId, robot.config.locked_joints) if below_wrist(jid)}
    out: dict[str, np.ndarray] = {}
    for i, obj in enumerate(geom.geometryObjects):
        if obj.parentJoint not in subtree:
            continue
        g = obj.geometry
        if hasattr(g, "points"):
            pts = np.asarray(g.points())
        else:  # a box
            pts = np.array(list(itertools.product((-1, 1), repeat=3))) * np.asarray(g.halfSide)
        M = T_hand * gdata.oMg[i]
        P = pts @ M.rotation.T + M.translation - face
        out[obj.name] = np.column_stack([P @ across, P @ normal, P @ axis])
    return out


def measure(robot, hand: str, posture: dict[str, float], links: tuple[str, ...] = (), margin: float = 0.0) -> dict:
    """Per finger link: reach past the palm face [m] and whether it stands in the rung's path
    (widened by ``margin`` on each side); overall: the farthest reach and the path clear, both
    over the links whose names contain one of ``links`` (all when empty)."""
    radius = robot.config.limbs[hand].surface.radius
    pts = finger_points(robot, hand, posture)
    rows = {}
    for name, P in pts.items():  # the grasp axis is at across = 0, height radius over the face
        # in the corridor: across the path of a held rung as the hand backs off along the normal
        rows[name] = {"reach_past_face_m": float(P[:, 1].max()),
                      "in_corridor": bool(np.any((np.abs(P[:, 0]) < radius + margin) & (P[:, 1] > radius)))}
    chosen = [n for n in rows if not links or any(k in n for k in links)]
    return {"links": rows,
            "reach_past_face_m": max(rows[n]["reach_past_face_m"] for n in chosen),
            "corridor_clear": not any(rows[n]["in_corridor"] for n in chosen)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robot", default="g1")
    ap.add_argument("--hand", default="left_hand", choices=("left_hand", "right_hand"))
    ap.add_argument("--search", default="", help="comma-separated locked joints to grid-search")
    ap.add_argument("--step", type=float, default=0.1, help="[rad] grid step of --search")
    ap.add_argument("--margin", type=float, default=0.0, help="[m] the corridor widened by this on each side")
    args = ap.parse_args(argv)

    from climb_core.errors import SpecError
    from climb_core.robot import load_robot

    try:
        robot = load_robot(args.robot)
        if args.hand not in robot.config.limbs or robot.config.limbs[args.hand].surface.kind != "grasp":
            raise SpecError("hand", f"{args.hand!r} has no grasp surface on {args.robot}")
        joints = [j for j in args.search.split(",") if j]
        for j in joints:
            if j not in robot.config.locked_joints:
                raise SpecError("search", f"{j!r} is not a locked joint of {args.robot}")
    except SpecError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    posture = {j: robot.config.locked_posture[j] for j in joints}
    if joints:
        full = robot.full_model
        grids = []
        for j in joints:
            jid = full.getJointId(j)
            lo, hi = full.lowerPositionLimit[full.joints[jid].idx_q], full.upperPositionLimit[full.joints[jid].idx_q]
            grids.append(np.round(np.arange(np.ceil(lo / args.step), np.floor(hi / args.step) + 1) * args.step, 6))
        links = tuple(j.removesuffix("_joint") + "_link" for j in joints)
        best = None
        for values in itertools.product(*grids):
            trial = dict(zip(joints, map(float, values)))
            m = measure(robot, args.hand, trial, links, args.margin)
            key = (round(m["reach_past_face_m"], 4), float(np.abs(values).sum()))  # ties: nearest the zero
            if m["corridor_clear"] and (best is None or key < best[0]):
                best = (key, trial)
        if best is None:
            print(f"no posture of {joints} keeps those links out of the rung's corridor", file=sys.stderr)
            print(json.dumps({"reach_past_face_m": None, "corridor_clear": False, "posture_rad": {}}))
            return 1
        posture = best[1]
    m = measure(robot, args.hand, posture, margin=args.margin)
    for name, row in sorted(m["links"].items()):
        print(f"{name:32s} reach past the palm face {row['reach_past_face_m'] * 1000:6.1f} mm"
              f"{'   IN the rung corridor' if row['in_corridor'] else ''}")
    print(json.dumps({"reach_past_face_m": round(m["reach_past_face_m"], 4), "corridor_clear": m["corridor_clear"],
                      "posture_rad": {j: round(v, 4) for j, v in posture.items()}}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
