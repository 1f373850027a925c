"""``rt2 learn promp``: learn an arm's hitting ProMP from the scripted teacher, and measure the fit.

The arm is ``--robot NAME|PATH.yaml`` (default the WAM; ``panda``, ``ur10``, ``xarm7`` or a robot config of
your own, docs/robots.md); the teacher moves that arm within its limits, from its home posture.

1. Draw ``--demos`` training and ``--held-out`` test requests (hitting point in x -1.6..-1.1,
   y -0.7..0.7, z 0.8..1.4 m, lab world; hitting time, racket normal and velocity, see
   ``policies.promp_demos.HitDistribution``); the teacher (``policies.teacher``) demonstrates each,
   redrawing the requests the WAM cannot meet (counted and reported).
2. Learn the ProMP by MAP-EM (NIW / IW priors) and by ML-EM, on all training demos and on the first
   ``--few``; report each one's held-out log-likelihood (nats per demonstration and per joint sample).
3. Condition the MAP primitive on each held-out hitting point at its hitting time (the duration
   chosen so the hit falls at the demonstrations' mean hit phase), on the racket position and on
   position + normal; report the racket error of the conditioned mean, the joint-limit excess of the
   conditioned mean trajectory and its distance to the teacher's own hitting posture.
4. Save the MAP primitive (all training demos) to ``--out`` (default ``data/promp/NAME_hitting.npz``, the
   file ``rt2 play --robot NAME`` loads: ``wam_hitting.npz`` for the WAM).

Same ``--seed``, same demonstrations, same primitive, same figures.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
from pathlib import Path

import numpy as np

PROMP_DIR = Path(__file__).resolve().parents[3] / "data" / "promp"
DEFAULT_OUT = PROMP_DIR / "wam_hitting.npz"


def default_promp(robot_name: str) -> Path:
    """The shipped hitting ProMP of an arm (``data/promp/NAME_hitting.npz``), what ``rt2 learn promp --robot NAME``
    writes and ``rt2 play --robot NAME`` loads."""
    return PROMP_DIR / f"{robot_name}_hitting.npz"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--demos", type=int, default=40, help="training demonstrations (default 40)")
    parser.add_argument("--held-out", type=int, default=20, help="held-out demonstrations (default 20)")
    parser.add_argument("--few", type=int, default=5, help="size of the small training set for MAP vs ML (default 5)")
    parser.add_argument("--n-basis", type=int, default=20, help="RBFs per joint (default 20)")
    parser.add_argument("--pseudo-demos", type=float, default=2.0, help="prior strength n0 of Sigma_w (default 2)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the requests and the teacher's variability")
    parser.add_argument("--out", type=Path, default=None,
                        help="where to save the primitive (default data/promp/NAME_hitting.npz of the --robot)")
    parser.add_argument("--no-save", action="store_true", help="measure only, write nothing")
    parser.add_argument("--robot", "--config", dest="robot", default=None, metavar="NAME|PATH.yaml",
                        help="the arm: a shipped one (wam, panda, ur10, xarm7; default wam) or a robot config (docs/robots.md)")
    parser.add_argument("--json", action="store_true", help="print JSON instead of tables")


#: the most RBFs per joint ``--n-basis`` may ask for (a demonstration of the teacher's has a few hundred samples; 20 fit it)
MAX_BASIS = 100


def _check_args(args) -> None:
    if args.demos < 2:
        raise ValueError(f"--demos must be >= 2, got {args.demos}")
    if args.held_out < 1:
        raise ValueError(f"--held-out must be >= 1, got {args.held_out}")
    if not 2 <= args.few <= args.demos:
        raise ValueError(f"--few must be in [2, --demos = {args.demos}], got {args.few}")
    if args.pseudo_demos <= 0:
        raise ValueError(f"--pseudo-demos must be > 0, got {args.pseudo_demos}")
    if not 2 <= args.n_basis <= MAX_BASIS:  # before the demonstrations are made (each needs as many samples as RBFs)
        raise ValueError(f"--n-basis must be in [2, {MAX_BASIS}] RBFs per joint, got {args.n_basis}")
    from harness.sim.robot.arms import load_arm

    args.arm = load_arm(args.robot)  # a bad arm: one line naming the file and the field
    if args.out is None:
        args.out = default_promp(args.arm.name)
    if args.out.suffix != ".npz":
        raise ValueError(f"--out must end in .npz, got {args.out}")
    if not args.no_save:
        from harness.common.outputs import check_output_file

        check_output_file(args.out, "--out")  # before the learning, not after (the save itself is atomic)


def _fit_table(train, test, n_basis, prior, few, joint_names, robot_id):
    from policies.promp import ProMP

    q_test, t_test = [d.q for d in test], [d.t_s for d in test]
    n_samples = np.array([d.q.size for d in test], float)
    rows, models = [], {}
    for n_train in sorted({few, len(train)}):
        subset = train[:n_train]
        for mode, p in (("MAP", prior), ("ML", None)):
            promp, info = ProMP.learn([d.q for d in subset], [d.t_s for d in subset], n_basis=n_basis, prior=p,
                                      joint_names=joint_names, robot_id=robot_id)
            ll = promp.log_likelihood(q_test, t_test)
            rows.append({"n_train": n_train, "mode": mode, "iterations": info.iterations, "converged": info.converged,
                         "heldout_ll_per_demo": float(np.mean(ll)), "heldout_ll_per_sample": float(np.sum(ll) / n_samples.sum()),
                         "heldout_ll_median": float(np.median(ll))})
            models[(n_train, mode)] = promp
    return rows, models


def _conditioning(promp, test, kin, hit_phase):
    """Condition on each held-out hitting point; racket error, limit excess, distance to the teacher's posture."""
    from policies.teacher import racket_kinematics

    out = {}
    for name, with_normal in (("position", False), ("position+normal", True)):
        fk, jac = racket_kinematics(kin, with_normal=with_normal)
        err_mm, ang_deg, excess, dist, failed = [], [], [], [], 0
        for d in test:
            duration = d.t_hit_s / hit_phase
            target = np.concatenate([d.x_hit_m, d.normal]) if with_normal else d.x_hit_m
            try:
                cond = promp.condition_on_task(d.t_hit_s, target, None, fk, jac, duration_s=duration)
            except ValueError:
                failed += 1
                continue
            t = np.linspace(0.0, duration, 400)
            q, _ = cond.mean_trajectory(t, duration_s=duration)
            q_hit = cond.mean_trajectory([d.t_hit_s], duration_s=duration)[0][0]
            x = fk(q_hit)
            err_mm.append(1e3 * np.linalg.norm(x[:3] - d.x_hit_m))
            if with_normal:
                ang_deg.append(np.degrees(np.arccos(np.clip(x[3:] @ d.normal / np.linalg.norm(x[3:]), -1, 1))))
            excess.append(float(np.maximum(np.maximum(kin.q_min - q, q - kin.q_max), 0.0).max()))
            dist.append(float(np.abs(q_hit - d.q_hit).max()))
        out[name] = {"failed": failed, "n": len(test),
                     "racket_error_mm_median": float(np.median(err_mm)) if err_mm else None,
                     "racket_error_mm_max": float(np.max(err_mm)) if err_mm else None,
                     "normal_error_deg_max": float(np.max(ang_deg)) if ang_deg else None,
                     "mean_outside_limits": int(np.sum(np.array(excess) > 1e-6)),
                     "limit_excess_rad_max": float(np.max(excess)) if excess else None,
                     "dist_to_teacher_posture_rad_median": float(np.median(dist)) if dist else None}
    return out


def run(args) -> int:
    from policies.promp_demos import HitDistribution, collect_demonstrations
    from policies.promp import NIWPrior
    from policies.teacher import ScriptedTeacher, TeacherOptions
    _check_args(args)
    kin = args.arm.kin
    teacher = ScriptedTeacher(kin, TeacherOptions())
    dist = HitDistribution()
    rng = np.random.default_rng(args.seed)
    train, rejected, reasons = collect_demonstrations(teacher, args.demos, rng, dist, desc="training demos")
    test, rejected_test, _ = collect_demonstrations(teacher, args.held_out, rng, dist, desc="held-out demos")
    prior = NIWPrior(pseudo_demos=args.pseudo_demos)
    rows, models = _fit_table(train, test, args.n_basis, prior, args.few, teacher.joint_names, teacher.robot_id)
    promp = models[(len(train), "MAP")]
    phases = np.array([d.hit_phase for d in train])
    cond = _conditioning(promp, test, kin, float(phases.mean()))
    result = {"seed": args.seed, "n_demos": len(train), "n_held_out": len(test), "n_basis": args.n_basis,
              "pseudo_demos": args.pseudo_demos, "rejected_requests": rejected, "rejected_held_out": rejected_test,
              "rejection_reasons": reasons, "hit_phase_mean": float(phases.mean()), "hit_phase_std": float(phases.std()),
              "duration_s": promp.duration_s, "duration_std_s": promp.duration_std_s, "fits": rows, "conditioning": cond}
    if not args.no_save:
        meta = {"made_by": "rt2 learn promp", "date": datetime.date.today().isoformat(), "seed": args.seed,
                "n_demos": len(train), "rejected_requests": rejected, "hit_phase_mean": result["hit_phase_mean"],
                "hit_phase_std": result["hit_phase_std"], "prior": dataclasses.asdict(prior),
                "hit_distribution": dataclasses.asdict(dist), "teacher": dataclasses.asdict(teacher.options),
                "robot_urdf": Path(kin.source).name, "robot_config": _config_name(args.arm.config)}
        promp = dataclasses.replace(promp, metadata=meta)
        result["saved"] = str(promp.save(args.out))
    if args.json:
        print(json.dumps(result, indent=1))
        return 0
    _print(result)
    return 0


def _config_name(config) -> str:
    """The robot config as the metadata names it: ``data/robot/NAME.yaml`` for a shipped arm, else its path."""
    from robot_models.config import ROBOT_CONFIG_DIR

    path = config.path
    return f"data/robot/{path.name}" if path is not None and path.resolve().parent == ROBOT_CONFIG_DIR else str(path)


def _print(r) -> None:
    print(f"rt2 learn promp  seed {r['seed']}: {r['n_demos']} training + {r['n_held_out']} held-out demonstrations, "
          f"{r['n_basis']} RBFs per joint")
    print(f"teacher: {r['rejected_requests']} infeasible training requests redrawn {r['rejection_reasons']}; "
          f"hit phase {r['hit_phase_mean']:.3f} +- {r['hit_phase_std']:.3f}, duration {r['duration_s']:.2f} "
          f"+- {r['duration_std_s']:.2f} s")
    print("\nheld-out log-likelihood (higher is better)")
    print(f"{'train':>6} {'fit':>4} {'iters':>6} {'nats/demo':>12} {'median':>12} {'nats/sample':>12}")
    for row in r["fits"]:
        print(f"{row['n_train']:>6} {row['mode']:>4} {row['iterations']:>6} {row['heldout_ll_per_demo']:>12.1f} "
              f"{row['heldout_ll_median']:>12.1f} {row['heldout_ll_per_sample']:>12.3f}")
    print("\nMAP primitive conditioned on each held-out hitting point (racket, at the hitting time)")
    print(f"{'via point':>16} {'failed':>7} {'err mm med':>11} {'err mm max':>11} {'normal deg':>11} "
          f"{'out of lim':>11} {'to teacher rad':>15}")
    for name, c in r["conditioning"].items():
        def f(v, fmt):
            return format(v, fmt) if v is not None else "-"
        print(f"{name:>16} {c['failed']:>3}/{c['n']:<3} {f(c['racket_error_mm_median'], '11.3f')} "
              f"{f(c['racket_error_mm_max'], '11.3f')} {f(c['normal_error_deg_max'], '11.2f')} "
              f"{c['mean_outside_limits']:>7}/{c['n']:<3} {f(c['dist_to_teacher_posture_rad_median'], '15.3f')}")
    if "saved" in r:
        print(f"\nsaved {r['saved']}")
