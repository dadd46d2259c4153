#!/usr/bin/env python3
"""Produce a motion-primitive library from its design cues (config/primitives/<robot>/<strategy>/).

    scripts/make_primitives.py --robot g1 --strategy forward [--check-steps 2]

Reads ``design.yaml`` (hand-written: seed holds, the moving limb's way-point offsets, the
sequences), walks the whole sequence once on the reference ladder from the initial fixture
(approach, mount, first climbing cycle, one more cycle) and, for every primitive at its first
occurrence, solves with the physics-constrained IK (planner_node.pcik):

- the end configuration: the ending stance's holds as regular contacts (a CoM primitive: its
  ``unload`` limb as a zero-force contact, the CoM pulled over ``com_over`` on the ground), the
  cost pulling toward the previous configuration moved with the stance;
- every way-point: the kept holds as regular contacts and the moving limb as a zero-force contact
  at the designed pose (offset from its start or target hold, ladder frame);

then stores the configurations in the ladder frame as ``library.yaml``. With ``--check-steps N``
(default 2) it finally plans an N-step climb of the reference ladder with the library it wrote
(the planner must adapt its own primitives) and fails (exit 1) if that does not succeed.
"""
from __future__ import annotations

import argparse
import pathlib
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robot", default="g1")
    ap.add_argument("--strategy", default="forward")
    ap.add_argument("--check-steps", type=int, default=2, help="plan this many cycles on the reference ladder (0: skip)")
    ap.add_argument("--verbose", action="store_true")
    ap.add_argument("--sequences", default="",
                    help="sequences walked through (development: e.g. `cycle` with --start-fixture ladder_4_contacts)")
    ap.add_argument("--start-fixture", default="", help="climb_core.fixtures name to start from (default: the design's)")
    ap.add_argument("--reference", default="", help="design on this ladder instead: a ladder name / file, or "
                    "inclination/spacing (e.g. 85/0.30) applied to the design's reference ladder")
    ap.add_argument("--all-variants", action="store_true",
                    help="build every variant listed under `variants:` in design.yaml (each on its reference ladder)")
    ap.add_argument("--no-write", action="store_true", help="do not write library.yaml (design development)")
    ap.add_argument("--dump", default="", help="save every designed configuration (and the failing one) to this .npz")
    args = ap.parse_args(argv)

    from climb_core.errors import ClimbError
    try:
        if args.all_variants:
            from planner_node.primitives import load_design

            worst = 0
            for key in (load_design(args.robot, args.strategy).get("variants") or {}):
                print(f"variant {key}", flush=True)
                worst = max(worst, build(argparse.Namespace(**{**vars(args), "reference": str(key)})))
            return worst
        return build(args)
    except ClimbError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


def variant_overrides(design: dict, reference: str) -> dict:
    """The `variants:` entry of design.yaml for an inclination/spacing reference (e.g. "85/0.30"),
    {} when there is none. Keys are compared as numbers (85/0.3 == 85/0.30)."""
    from climb_core.errors import SpecError

    variants = design.get("variants") or {}
    if not isinstance(variants, dict):
        raise SpecError("design.variants", "must be a mapping inclination/spacing -> overrides")
    if not reference or "/" not in reference or reference.endswith((".yaml", ".yml")):
        return {}

    def key(text: str, field: str) -> tuple[float, float]:
        try:
            a, b = (float(x) for x in str(text).split("/"))
        except ValueError:
            raise SpecError(field, f"expected inclination/spacing like 85/0.30, got {text!r}") from None
        return round(a, 6), round(b, 6)

    want = key(reference, "reference")
    for name, over in variants.items():
        if key(name, f"design.variants.{name}") == want:
            if not isinstance(over, dict):
                raise SpecError(f"design.variants.{name}", "must be a mapping of design overrides")
            return over
    return {}


def merge_design(base: dict, over: dict, field: str = "design") -> dict:
    """Deep merge of a variant's overrides into the design: mappings are merged key by key,
    anything else (numbers, lists such as `via` or `search_base_offsets`) replaced; a null value
    deletes the key (e.g. a pelvis cue the variant does not want)."""
    import copy

    out = copy.deepcopy(base)
    for k, v in over.items():
        if v is None:
            out.pop(k, None)
        elif isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = merge_design(out[k], v, f"{field}.{k}")
        else:
            out[k] = copy.deepcopy(v)
    return out


def build(args: argparse.Namespace) -> int:
    import pinocchio as pin

    from climb_core import feasibility, fixtures
    from climb_core import holds as holds_mod
    from climb_core.contact import Stance
    from climb_core.environment import build_environment
    from climb_core.errors import InfeasibleError, SpecError
    from climb_core.ladder import load_scenario
    from climb_core.robot import load_robot
    from planner_node import pcik
    from planner_node.adapt import AdaptContext, build_path, failure_name, ground_foot_x, stance_anchor
    from planner_node.primitives import (DESIGN_FILE, Primitive, PrimitiveLibrary, library_dir, reference_key,
                                         variant_file_name,
                                         load_design, parse_primitive, point_to_ladder, save_library, to_ladder,
                                         vector_to_world)
    from planner_node.settings import load_settings, replace

    design = load_design(args.robot, args.strategy)
    # per-variant cue overrides (design.yaml `variants:`): only for a variant's build, never the main library
    design = merge_design({k: v for k, v in design.items() if k != "variants"},
                          variant_overrides(design, args.reference))
    robot = load_robot(design.get("robot", args.robot))
    scenario = reference_scenario(design["reference_ladder"], args.reference)
    env = build_environment(scenario)
    settings = load_settings()
    # the designed way-points keep the full environment margins from the robot's own links too,
    # so that the adaptation (which allows closer self distances) has room around them
    # (a variant may ask for less with `design_self_collision_margin` [m]: never below the IK's own
    # self margin, so its way-points still satisfy every margin the planner's checks use)
    self_margin = float(design.get("design_self_collision_margin", settings.pcik.collision_margin))
    if not settings.pcik.self_collision_margin <= self_margin <= settings.pcik.collision_margin:
        raise SpecError("design.design_self_collision_margin",
                        f"must be within [{settings.pcik.self_collision_margin}, {settings.pcik.collision_margin}] m")
    settings = replace(settings, "pcik", self_collision_margin=self_margin)
    settings = replace(settings, "planning", self_collision_margin=max(settings.planning.self_collision_margin,
                                                                        min(self_margin,
                                                                            settings.planning.collision_margin)))
    cfg = design_hold_config(feasibility.load_config(), design)
    plan_cfg = AdaptContext(robot, env, _empty_library(robot, design), settings, cfg).check_cfg
    H = design["holds"]
    side = {"left_foot": 1.0, "right_foot": -1.0, "left_hand": 1.0, "right_hand": -1.0}
    stance, q = fixtures.get(args.start_fixture or design.get("initial_fixture", "standing"), robot, env)
    posture_climb = design.get("posture", {}).get("climbing", {}) or {}
    posture_stand = design.get("posture", {}).get("standing", {}) or {}

    def with_posture(q_ref: np.ndarray, values: dict) -> np.ndarray:
        out = q_ref.copy()
        for joint, value in values.items():
            jid = robot.model.getJointId(joint)
            if jid >= robot.model.njoints:
                raise SpecError("design.posture", f"unknown joint {joint!r}")
            out[robot.model.joints[jid].idx_q] = float(value)
        return out

    def pinned(hold, q_ref: np.ndarray):
        """A kept grasp keeps the roll it has at q_ref (the IK would otherwise let it drift about the
        rung from primitive to primitive); other holds: None (their hold pose). design.yaml
        ``pin_grasp_roll: false`` leaves the roll free (a robot whose wrists are its binding joints
        needs the roll the equilibrium asks for)."""
        if not hold.bilateral or not design.get("pin_grasp_roll", True):
            return None
        return np.array(robot.T_world_surface(hold.limb, q_ref))

    def cues(q_ref: np.ndarray, spec: dict) -> np.ndarray:
        """The primitive's own posture cues: joint targets and a base offset (ladder frame [m])."""
        out = with_posture(q_ref, spec.get("posture", {}) or {})
        if spec.get("base_offset") is not None:
            out[:3] += vector_to_world(env, np.asarray(spec["base_offset"], dtype=float))
        return out

    def rung_of(limb: str, st: Stance) -> int:
        h = st.hold(limb)
        return 0 if h is None or h.env_surface == "ground" else int(h.env_surface.split("_")[1])

    def target_hold(spec: dict, limb: str, st: Stance):
        t = spec["target"]
        if t["surface"] == "ground":
            p_l = np.array([ground_foot_x(H, float(scenario.ladder.inclination_deg)), side[limb] * H["ground_foot_y"],
                            0.0])
            T = env.T_world_ladder
            p_w = T[:3, :3] @ p_l + T[:3, 3]
            yaw = float(np.arctan2(T[1, 0], T[0, 0]))
            return holds_mod.make_hold(robot, env, limb, "ground", position=p_w, yaw=yaw, params=cfg.holds)
        if t["rule"] == "next":
            k = rung_of(limb, st) + 1
        elif t["rule"] == "mount":
            k = int(H["mount_rung"])
        else:
            k = max(rung_of(f, st) for f in ("left_foot", "right_foot")) + int(H["hands_above_feet_rungs"])
        s = side[limb] * (H["foot_s"] if "foot" in limb else H["hand_s"])
        return holds_mod.make_hold(robot, env, limb, f"rung_{k}", s, params=cfg.holds)

    dump: list[tuple[str, np.ndarray]] = []

    def solve(contacts, q_seed, q_target, *, excl=(), com_target=None, what="", cue: Stance | None = None):
        """PCIK; with ``cue`` (the kept holds) the zero-force pose of the moving limb is a design
        cue: missing it by up to via_tolerance is fine as long as q is feasible on the kept holds."""
        res = pcik.solve(robot, env, q_seed, contacts, q_target=q_target, params=settings.pcik,
                         feasibility_cfg=plan_cfg, extra_exclusions=excl, com_target=com_target,
                         final_check=cue is None)
        dump.append((("" if res.success else "FAILED ") + what, res.q))
        if cue is not None:
            if res.position_error <= float(design.get("via_tolerance", 0.03)):
                chk = pcik.check_with_exclusions(robot, env, res.q, cue, plan_cfg, extra_exclusions=excl)
                if chk.feasible:
                    return res.q
                raise InfeasibleError(chk.violated[0], f"{what}: {chk.summary()}")
        if not res.success:
            named = failure_name(res.check) if res.check is not None and not res.check.feasible else ""
            raise InfeasibleError(res.failure or "pcik", f"{what}: {pcik.describe_failure(res)} {named}")
        return res.q

    offsets = [np.array(o, dtype=float) for o in design.get("search_base_offsets", [[0.0, 0.0, 0.0]])]

    def solve_searching(contacts, q_seed, q_target, *, com_target=None, what="", also=()):
        """solve(), retried with the pelvis target moved by the design's search offsets (L frame);
        ``also``: (stance, exclusions) pairs the result must be feasible on too."""
        first = None
        for k, off in enumerate(offsets):
            qt = q_target.copy()
            qt[:3] += vector_to_world(env, off)
            qs = q_seed.copy()
            qs[:3] += vector_to_world(env, off)
            try:
                q_out = solve(contacts, qs if k else q_seed, qt, com_target=com_target, what=f"{what} (offset {off})")
                for st, excl in also:
                    chk = pcik.check_with_exclusions(robot, env, q_out, st, plan_cfg, extra_exclusions=excl)
                    if not chk.feasible:
                        raise InfeasibleError(chk.violated[0], f"{what}: without {excl[0][0]}: {chk.summary()}")
                return q_out
            except InfeasibleError as exc:
                if args.verbose:
                    print(f"    {what} offset {off}: {exc}", file=sys.stderr)
                first = first or exc
        raise first

    def checked_milestones(waypoints, stance_t, limb, zone, what):
        """The planner's own path construction on the reference ladder: the interpolation between
        the designed way-points must be feasible; colliding sections get extra way-points."""
        path, milestones, failure = build_path(ctx, list(waypoints), stance_t, limb, zone)
        if path is None:
            if args.verbose:  # where it failed: the first infeasible section of the last try
                from planner_node.adapt import ContactProjector, _bad_sections, _interpolate_milestones

                p = _interpolate_milestones(ctx, milestones, ContactProjector(ctx, stance_t, milestones[0]))
                for lo, hi, r in (_bad_sections(ctx, p, stance_t, limb, zone) if p else [])[:3]:
                    where = robot.T_world_surface(limb, p[lo])[:3, 3].round(3) if limb else ""
                    print(f"    infeasible {lo}..{hi} of {len(p)}: {r.violated} {r.details.get('collisions', '')} "
                          f"limb at {where}", file=sys.stderr)
                    dump.append((f"BAD {what} {lo}", p[lo]))
            raise InfeasibleError(failure or "path", f"{what}: path between the designed way-points")
        dump.extend((f"{what} milestone", m) for m in milestones)
        return milestones

    def pose_at(hold, offset, frame="ladder"):
        """Pose of the limb surface at ``offset`` [m] from its pose on ``hold``, the offset in the
        ladder frame or in the hold's surface frame (z = into the surface: a grasp's palm normal)."""
        T = np.array(holds_mod.hold_target(robot, env, hold, params=cfg.holds).T_world_surface)
        off = np.asarray(offset, dtype=float)
        T[:3, 3] += T[:3, :3] @ off if frame == "surface" else vector_to_world(env, off)
        return T

    ctx = AdaptContext(robot, env, _empty_library(robot, design), settings, cfg)
    order = []
    # walked in climbing order: a `first_cycle` (the cycle from the ground) comes before `cycle`
    # (the steady-state cycle from a rung), whatever their order in the file
    walk = list(design["sequences"])
    walk.sort(key=lambda n: {"approach": 0, "mount": 1, "first_cycle": 2, "cycle": 3}.get(n, 4))
    for name in (args.sequences.split(",") if args.sequences else walk):
        order += list(design["sequences"].get(name, []))
    prims: dict[str, Primitive] = {}
    mount_height = hands_height = None
    t_start = time.perf_counter()

    def design_one(name, q, stance, mount_height, hands_height):
        spec = primitive_spec(design, name)
        kind = spec["kind"]
        t0 = time.perf_counter()
        if kind == "com":
            unload = spec.get("unload", "")
            com_over = spec.get("com_over", "")
            contacts = [pcik.ContactSpec(h.limb, pcik.ZERO_FORCE if h.limb == unload else pcik.REGULAR, hold=h,
                                         pose=pinned(h, q)) for h in stance.holds]
            com_target = None
            if com_over in ("left_foot", "right_foot"):
                com_target = stance.hold(com_over).centre[:2].copy()
            elif com_over == "centre":
                com_target = np.mean([stance.hold(f).centre for f in ("left_foot", "right_foot")], axis=0)[:2]
            if com_target is not None:
                off = vector_to_world(env, np.array(list(spec.get("com_offset", [0.0, 0.0])) + [0.0]))
                com_target = com_target + off[:2]
                axes = spec.get("com_axes", "xy")
                if "x" not in axes:
                    com_target[0] = np.nan  # free along x (the hands hold the rest)
                if "y" not in axes:
                    com_target[1] = np.nan
            q_target = with_posture(q, posture_climb if any(h.bilateral for h in stance.holds) else posture_stand)
            q_target = cues(q_target, spec)
            if spec.get("base_above_feet") is not None:
                feet = np.mean([stance.hold(f).centre for f in ("left_foot", "right_foot")], axis=0)
                q_target[:3] = feet + vector_to_world(env, np.asarray(spec["base_above_feet"], dtype=float))
            q_end = solve_searching(contacts, q, q_target, com_target=com_target, what=name)
            waypoints = checked_milestones([q, q_end], stance, "", [], name)
            end_stance = stance
            target = None
        else:
            limb = spec["limb"]
            old = stance.hold(limb)
            new = target_hold(spec, limb, stance)
            end_stance = stance.with_hold(new)
            kept = Stance(tuple(h for h in end_stance.holds if h.limb != limb))
            d = stance_anchor(end_stance) - stance_anchor(stance)
            q_target = q.copy()
            q_target[:3] += d
            q_target = with_posture(q_target, posture_climb if any(h.bilateral for h in end_stance.holds)
                                    else posture_stand)
            q_target = cues(q_target, spec)
            if spec.get("base_above_feet") is not None:
                feet = np.mean([end_stance.hold(f).centre for f in ("left_foot", "right_foot")], axis=0)
                q_target[:3] = feet + vector_to_world(env, np.asarray(spec["base_above_feet"], dtype=float))
            end_unload = list(spec.get("end_unload") or [limb])
            # the new hold at its nominal pose (a grasp's roll pinned: the palm on the robot's side)
            nominal = np.array(holds_mod.hold_target(robot, env, new, params=cfg.holds).T_world_surface)
            contacts = [pcik.ContactSpec(h.limb, pcik.ZERO_FORCE if h.limb == end_unload[0] else pcik.REGULAR, hold=h,
                                         pose=nominal if h.limb == limb else pinned(h, q))
                        for h in end_stance.holds]
            q_end = solve_searching(contacts, q_target, q_target, what=f"{name} end",
                                    also=[(end_stance.without(u), [(u, end_stance.hold(u).env_surface)])
                                          for u in [limb] + end_unload if end_stance.hold(u) is not None])
            # the designed limb poses (cues) and pelvis targets, start and end included
            poses = [np.array(robot.T_world_surface(limb, q))]
            blends = [q]
            vias = spec.get("via", [])
            for i, via in enumerate(vias):
                frame = via.get("frame", "ladder")
                offset = np.asarray(via["offset"], dtype=float).copy()
                if frame == "ladder":
                    offset[1] *= side[limb]  # ladder-frame y is "outward": mirrored for right limbs
                # from where the limb actually is at the start / end configuration (a grasp's roll
                # about the rung is free: the IK's choice, not the hold's nominal one)
                T = np.array(robot.T_world_surface(limb, q if via["from"] == "start" else q_end))
                T[:3, 3] += T[:3, :3] @ offset if frame == "surface" else vector_to_world(env, offset)
                q_blend = pin.interpolate(robot.model, q, q_end, (i + 1) / (len(vias) + 1))
                if via.get("base_above_feet") is not None:  # pelvis cue: vs the end stance's mean foot hold
                    feet = np.mean([end_stance.hold(f).centre for f in ("left_foot", "right_foot")], axis=0)
                    q_blend[:3] = feet + vector_to_world(env, np.asarray(via["base_above_feet"], dtype=float))
                poses.append(T)
                blends.append(q_blend)
            poses.append(np.array(robot.T_world_surface(limb, q_end)))
            blends.append(q_end)
            # straight limb motions between the cues: intermediate poses every cartesian_step
            step = float(design.get("cartesian_step", 0.04))
            radius = (settings.interpolation.exclusion_distance_hand if limb.endswith("hand")
                      else settings.interpolation.exclusion_distance_foot)
            waypoints = [q]
            for k in range(len(poses) - 1):
                Ma, Mb = pin.SE3(poses[k]), pin.SE3(poses[k + 1])
                n_sub = max(1, int(np.ceil(np.linalg.norm(Mb.translation - Ma.translation) / step)))
                last = k == len(poses) - 2
                for j in range(1, n_sub + (0 if last else 1)):
                    t = j / n_sub
                    T = (Ma * pin.exp6(t * pin.log6(Ma.actInv(Mb)))).homogeneous
                    q_cue = pin.interpolate(robot.model, blends[k], blends[k + 1], t)
                    excl = [(limb, h.env_surface) for h in (old, new)
                            if h is not None and np.linalg.norm(T[:3, 3] - ctx.hold_origin(h)) <= radius]
                    contacts = ([pcik.ContactSpec(h.limb, pcik.REGULAR, hold=h, pose=pinned(h, q)) for h in kept.holds]
                                + [pcik.ContactSpec(limb, pcik.ZERO_FORCE, pose=T, soft=True)])
                    what = f"{name} segment {k} step {j}/{n_sub}"
                    try:
                        q_via = solve(contacts, waypoints[-1], q_cue, excl=excl, what=what, cue=kept)
                    except InfeasibleError:  # second seed: the blend of the designed cues
                        q_via = solve(contacts, q_cue, q_cue, excl=excl, what=what + " (blend seed)", cue=kept)
                    waypoints.append(q_via)
            waypoints.append(q_end)
            waypoints = checked_milestones(waypoints, kept, limb, [old, new], name)
            target = new
            if spec["target"].get("rule") == "mount" and mount_height is None:
                mount_height = env.surfaces[new.env_surface].top_z - _feet_z(stance)
            if spec["target"].get("rule") == "above_feet" and hands_height is None:
                hands_height = env.surfaces[new.env_surface].top_z - _feet_z(end_stance)
        if name not in prims:
            d = dict(spec)
            if kind == "limb":
                d["end_unload"] = list(spec.get("end_unload") or [spec["limb"]])
            d["waypoints"] = [to_ladder(env, w) for w in waypoints]
            d["anchor_start"] = point_to_ladder(env, stance_anchor(stance))
            d["anchor_end"] = point_to_ladder(env, stance_anchor(end_stance))
            if target is not None:
                d["target_centre"] = point_to_ladder(env, target.centre)
                d["seed_s"] = H["foot_s"] if "foot" in spec["limb"] else H["hand_s"]
            prims[name] = parse_primitive(name, d, robot.model.nq, "design.primitives")
        if args.verbose:
            print(f"  {name:26s} {len(waypoints)} way-points  {time.perf_counter() - t0:5.2f} s", file=sys.stderr)
        return mount_height, hands_height, waypoints[-1], end_stance

    fallback = bool(args.reference) and str(design.get("fallback", "")) == "main"
    # a partial variant may also leave primitives to the main library on purpose (design.yaml
    # `main_primitives: [...]`): e.g. the hand placements, whose target rung follows the designed
    # hand height of the library they come from
    use_main = [str(n) for n in (design.get("main_primitives") or [])]
    if use_main and not fallback:
        raise SpecError("design.main_primitives", "needs `fallback: main` (a variant built with --reference)")
    main_ctx = None
    try:
        for name in order:
            try:
                if name in use_main:
                    raise InfeasibleError("design.main_primitives", f"{name}: the main library's primitive")
                mount_height, hands_height, q, stance = design_one(name, q, stance, mount_height, hands_height)
            except InfeasibleError as exc:
                if not fallback or name in prims:
                    raise
                # partial variant (design.yaml `fallback: main`): a primitive whose cues cannot be
                # realised on this reference ladder is not stored; the walk goes on with the main
                # library's primitive adapted by the planner itself (as the planner will do)
                if main_ctx is None:
                    from planner_node.primitives import load_library as _load_main

                    main_lib = _load_main(args.robot, args.strategy, nq=robot.model.nq)
                    main_ctx = AdaptContext(robot, env, main_lib, load_settings(), cfg)
                q, stance = _adapt_with(main_ctx, name, q, stance)
                print(f"  {name}: not designed ({exc.constraint if hasattr(exc, 'constraint') else exc}); "
                      f"the main library's primitive adapts here", file=sys.stderr)
    finally:
        if args.dump:
            np.savez(args.dump, names=np.array([n for n, _ in dump]), q=np.array([x for _, x in dump]))

    if args.no_write:
        print(f"designed {len(prims)} primitives (not written)")
        return 0
    if args.reference and (mount_height is None or hands_height is None):
        # a variant designed for part of the sequences (e.g. only the climbing cycle): the rung rules
        # keep the main library's heights; the planner falls back to the main library's primitives
        from planner_node.primitives import load_library as _load

        main = _load(args.robot, args.strategy, nq=robot.model.nq)
        mount_height = main.mount_height if mount_height is None else mount_height
        hands_height = main.hands_above_feet_height if hands_height is None else hands_height
    if mount_height is None or hands_height is None:
        raise SpecError("design.sequences", "the sequences need a mount and an above_feet hand primitive")
    lib = PrimitiveLibrary(
        robot=robot.config.name, strategy=args.strategy, facing=str(design.get("facing", "forward")),
        reference_ladder=_scenario_dict(design["reference_ladder"], scenario),
        joint_names=tuple(robot.joint_names),
        sequences=_stored_sequences(design["sequences"], prims, bool(args.reference)),
        primitives=prims,
        holds={k: float(v) for k, v in H.items()}, mount_height=float(mount_height),
        hands_above_feet_height=float(hands_height), initial_fixture=str(design.get("initial_fixture", "standing")),
        generated_by=f"scripts/make_primitives.py --robot {args.robot} --strategy {args.strategy}")
    folder = library_dir(args.robot, args.strategy)
    header = (f"# GENERATED by {lib.generated_by} from {DESIGN_FILE} - do not edit by hand.\n"
              f"# Way-points: pelvis pose in the ladder base frame (x y z [m], quaternion x y z w), then joints [rad]\n"
              f"# in joint_names order. Heights [m]. See planner_node/primitives.py and docs/planner.md.\n")
    file_name = variant_file_name(*reference_key(lib)) if args.reference else "library.yaml"
    path = save_library(lib, folder, header, file_name)
    print(f"wrote {path} ({len(prims)} primitives, {time.perf_counter() - t_start:.1f} s)")
    if args.check_steps > 0:
        from planner_node.climb_planner import plan_climb
        from planner_node.primitives import load_library

        if args.reference:  # a variant: the planner as it runs (every library, this one nearest)
            res = plan_climb(robot, env, args.check_steps, settings=load_settings(), feasibility_cfg=cfg)
        else:
            lib2 = load_library(args.robot, args.strategy, nq=robot.model.nq, path=path)
            res = plan_climb(robot, env, args.check_steps, library=lib2, settings=load_settings(), feasibility_cfg=cfg)
        print(f"check: {args.check_steps}-step climb of {env.name}: success={res.success} "
              f"time={res.plan_time_s:.2f} s {res.failure_constraint} {res.failure_detail}")
        if not res.success:
            return 1
    return 0


def _stored_sequences(sequences: dict, prims: dict, variant: bool) -> dict:
    """The sequences whose primitives were all designed. The planner walks a variant's own
    sequences (approach, mount, first_cycle, cycle) as soon as it has a `cycle`, so a partial
    variant (`fallback: main`) that lost its mount keeps no sequence at all: the planner then takes
    the main library's sequence and adapts this variant's primitives where it has them."""
    out = {k: tuple(v) for k, v in sequences.items() if all(n in prims for n in v)}
    if variant and "cycle" in out and not all(k in out for k in sequences if k in ("approach", "mount")):
        print(f"  partial variant: {', '.join(k for k in sequences if k not in out)} not designed; "
              f"the main library's sub-task sequence is used", file=sys.stderr)
        return {}
    return out or ({} if variant else {"cycle": tuple(prims)})


def design_hold_config(cfg, design: dict):
    """The feasibility config with the design's hold placement: ``holds.foot_on_rung_offset`` [m]
    (sole centre this far behind the rung, i.e. the ball of the foot on the rung) and
    ``holds.foot_on_rung_pitch_deg`` [deg] (the sole pitched toes up on a round rung, tangent
    where it touches) replace the config/feasibility.yaml values for the IK targets. The check
    itself accepts any sole placement with the rung line under the sole polygon, and reads a
    hold's pitch from its normals, so the frozen check still judges the result."""
    import dataclasses

    from climb_core.errors import SpecError

    holds = design.get("holds") or {}
    changes = {}
    for key, lo, hi, unit in (("foot_on_rung_offset", -0.1, 0.1, "m"), ("foot_on_rung_pitch_deg", -30.0, 30.0, "deg")):
        if holds.get(key) is None:
            continue
        value = float(holds[key])
        if not lo <= value <= hi:
            raise SpecError(f"design.holds.{key}", f"must be within [{lo:g}, {hi:g}] {unit}")
        changes[key] = value
    if not changes:
        return cfg
    return dataclasses.replace(cfg, holds=dataclasses.replace(cfg.holds, **changes))


def _adapt_with(ctx, name: str, q, stance):
    """The planner's Adapt-Primitive of the main library's primitive ``name`` from (q, stance):
    the first of ``attempts_per_subtask`` attempts that succeeds (InfeasibleError otherwise)."""
    from climb_core.errors import InfeasibleError
    from planner_node.adapt import ClimbState, adapt_primitive
    from planner_node.msp import Step, branch_rng

    prim = ctx.library.primitives.get(name)
    if prim is None:
        raise InfeasibleError("design", f"{name}: not in the main library either")
    last = None
    for j in range(ctx.settings.planning.attempts_per_subtask):
        out = adapt_primitive(ctx, prim, ClimbState(q, stance), j, branch_rng(ctx.settings.planning.seed, [j]))
        if isinstance(out, Step):
            return out.state.q, out.state.stance
        last = out
    raise InfeasibleError(last.constraint if last else "design", f"{name}: main library primitive: {last}")


def primitive_spec(design: dict, name: str) -> dict:
    """A primitive's design cues; ``same_as: <other>`` starts from another primitive's cues (e.g.
    the first cycle's copy of a steady-state primitive), the entry's own keys on top."""
    from climb_core.errors import SpecError

    prims = design.get("primitives") or {}
    if name not in prims:
        raise SpecError(f"design.primitives.{name}", "not defined (named in a sequence)")
    spec = dict(prims[name])
    seen = {name}
    while "same_as" in spec:
        base = str(spec.pop("same_as"))
        if base in seen or base not in prims:
            raise SpecError(f"design.primitives.{name}.same_as", f"must name another primitive; got {base!r}")
        seen.add(base)
        spec = merge_design(dict(prims[base]), spec)
    return spec


def reference_scenario(default: str, override: str):
    """The scenario the way-points are designed on: ``override`` as inclination/spacing applied to
    the default reference ladder, a ladder name / file, or the default itself."""
    import copy

    import yaml

    from climb_core.ladder import load_scenario, parse_scenario

    if not override:
        return load_scenario(default)
    if "/" in override and not override.endswith((".yaml", ".yml")):
        inc, sp = (float(x) for x in override.split("/"))
        data = copy.deepcopy(yaml.safe_load((ROOT / "config" / "ladders" / f"{default}.yaml").read_text()))
        data["ladder"]["inclination_deg"] = inc
        data["ladder"]["rung_spacing"] = sp
        return parse_scenario(data, name=f"{default}_{inc:g}_{sp:.2f}")
    return load_scenario(override)


def _feet_z(stance) -> float:
    zs = [h.centre[2] for h in stance.holds if h.limb.endswith("foot")]
    return float(np.mean(zs)) if zs else 0.0


def _scenario_dict(name: str, scenario) -> dict:
    """The reference ladder as stored in the library: the spec file's mapping, with the
    inclination and spacing the way-points were actually designed on."""
    import yaml

    path = ROOT / "config" / "ladders" / f"{name}.yaml"
    data = yaml.safe_load(path.read_text()) if path.is_file() else {"ladder": {}}
    data["ladder"]["inclination_deg"] = float(scenario.ladder.inclination_deg)
    data["ladder"]["rung_spacing"] = float(scenario.ladder.rung_spacing)
    data["name"] = scenario.name
    return data


def _empty_library(robot, design):
    from planner_node.primitives import PrimitiveLibrary

    return PrimitiveLibrary(robot=robot.config.name, strategy=str(design.get("strategy", "")),
                            facing=str(design.get("facing", "forward")), reference_ladder={},
                            joint_names=tuple(robot.joint_names), sequences={}, primitives={},
                            holds={k: float(v) for k, v in design["holds"].items()}, mount_height=0.0,
                            hands_above_feet_height=0.0)


if __name__ == "__main__":
    sys.exit(main())
