"""One served ball in closed loop: launcher -> physics -> cameras/tracker -> filter -> policy -> WAM -> racket.

Timing model (docs/play.md, "loop and timing"). One clock for everything, 0 at the serve:

* the WAM runs at its control rate (500 Hz, 2 ms ticks); at the start of each tick the observations
  that have arrived (capture time + the tracker's latency <= now) go to the filter, in capture order,
  then the policy steps (it re-plans at most every ``replan_period_s`` and commands the WAM), then the
  simulated WAM runs the tick;
* the ball world runs at 1 ms with swept contacts; the racket is the disk of the racket frame at the
  TRUE joint angles of the simulated WAM (``RacketState.from_pose``, velocity J_v(q) qdot), linearly
  interpolated within a WAM tick;
* the tracker captures frame sets at phase + k / rate_hz (phase drawn per ball); the observation source
  sees the true ball (interpolated to the capture time) and the true arm. Captures stop at the policy's
  commit point (nothing after it can change the swing) and after the racket hit;
* the ball is followed until its return lands (or hits the net / the floor), or, unhit, until it falls
  to the floor, passes the robot or ``max_flight_s`` runs out.

Outcome: ``no_attempt`` (the policy never started a movement; its last reason is kept), ``no_hit`` (a
movement, no racket contact), or ``harness.sim.physics.classify_return`` of the events after the hit
(``landed_in``, ``net``, ``missed_table``, ``own_side``, ``in_flight``). Success = ``landed_in``:
the racket hit the ball and it bounced first on the opponent's half.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass, field

import numpy as np

from harness.sim.physics import BallWorld, EventKind, RacketState, WorldOptions, classify_return
from harness.sim.robot import SimulatedWam, SimWamOptions
from policies.hitting import NO_PREDICTION, HittingPolicy, PolicyStatus

__all__ = ["BallRecord", "BallResult", "PlaySession", "SessionOptions", "ball_over", "ball_result", "lerp_racket", "world_summary"]


@dataclass(frozen=True)
class SessionOptions:
    """max_flight_s : an unhit ball is followed at most this long; after_hit_s : a hit one this long
    after the contact; past_robot_x_m : an unhit ball beyond this x is gone; world : ball world options;
    plan_latency_s : how long a planning step of the policy takes (0: no time at all, the paper's
    setting): a step made at t plans for t + plan_latency_s, from the observations that arrived by t, and
    its command reaches the robot at t + plan_latency_s -- what a live policy process does with its lead
    (harness/experiments/play/live.py), here with a fixed, reproducible latency."""

    max_flight_s: float = 2.5
    after_hit_s: float = 2.0
    past_robot_x_m: float = -2.6
    world: WorldOptions = field(default_factory=WorldOptions)
    plan_latency_s: float = 0.0

    def __post_init__(self):
        if not (self.max_flight_s > 0 and self.after_hit_s > 0):
            raise ValueError(f"SessionOptions need max_flight_s > 0 and after_hit_s > 0, got {self}")
        lat = self.plan_latency_s
        if isinstance(lat, bool) or not isinstance(lat, (int, float)) or not 0.0 <= lat <= 0.5:
            raise ValueError(f"SessionOptions.plan_latency_s must be a number of seconds in [0, 0.5], got {lat!r}")


class _LateCommands:
    """The robot as a policy that needs ``latency_s`` to plan sees it: states now, commands ``latency_s`` later
    (:meth:`deliver` hands them to the robot when the session's clock reaches them)."""

    def __init__(self, wam, latency_s: float):
        self.wam, self.latency_s, self.now_s = wam, float(latency_s), 0.0
        self.control_rate_hz, self.n_joints = wam.control_rate_hz, wam.n_joints
        self._queue: collections.deque = collections.deque()

    def read_state(self):
        return self.wam.read_state()

    def command_trajectory(self, t_s, q, qdot=None) -> None:
        self._queue.append((self.now_s + self.latency_s, np.array(t_s, float), np.array(q, float),
                            None if qdot is None else np.array(qdot, float)))

    def deliver(self, t_s: float) -> None:
        while self._queue and self._queue[0][0] <= t_s + 1e-12:
            _, ts, q, qd = self._queue.popleft()
            self.wam.command_trajectory(ts, q, qd)


@dataclass(frozen=True)
class BallResult:
    """What happened to one ball (JSON-ready: plain floats, lists, strings)."""

    ball: int
    outcome: str
    success: bool
    attempted: bool
    reason: str
    n_frames: int
    n_positions: int
    n_accepted: int
    n_plans: int
    t_hit_planned_s: float | None
    hit_point_planned_m: list | None
    contact_t_s: float | None
    contact_m: list | None
    landing_xy_m: list | None
    closest_approach_m: float
    serve_speed_mps: float
    spin_kind: str
    plan_failures: dict = field(default_factory=dict)  #: why policy steps made no plan (first words -> count)

    def to_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class BallRecord:
    """Everything of one ball for the session log (arrays grow during the run)."""

    truth_t_s: list = field(default_factory=list)
    truth_m: list = field(default_factory=list)
    observations: list = field(default_factory=list)  # (BallObservation, FilterUpdate)
    filter_states: list = field(default_factory=list)  # FilterState after each delivery
    plans: list = field(default_factory=list)
    robot_t_s: list = field(default_factory=list)
    q_reported: list = field(default_factory=list)
    qdot_reported: list = field(default_factory=list)
    q_true: list = field(default_factory=list)
    q_command: list = field(default_factory=list)
    events: list = field(default_factory=list)
    images: list = field(default_factory=list)  # (t_s, [(camera, (H, W, 3) uint8)]) of the logged frame sets


class PlaySession:
    """Plays single balls (:meth:`run`) with one tracker profile, filter, policy and WAM model.

    kinematics : robot_models.WamKinematics; promp : the hitting ProMP; source : an observation source
    (harness.experiments.play.sources); filter_factory : callable () -> a fresh ball filter (policies.filters);
    profile : the tracker's :class:`~harness.experiments.play.profiles.TrackerProfile` (rate, latency)
    """

    def __init__(self, kinematics, promp, source, filter_factory, profile, *, policy_options=None,
                 sim_options: SimWamOptions | None = None, options: SessionOptions = SessionOptions(), ball_params=None):
        from policies.hitting import HittingOptions

        self.kin, self.source, self.profile, self.options = kinematics, source, profile, options
        self.filter = filter_factory()
        self.params = ball_params if ball_params is not None else self.filter.params
        self.policy = HittingPolicy(promp, kinematics, policy_options or HittingOptions(), ball_params=self.params,
                                    table=options.world.table)
        self.sim_options = sim_options or SimWamOptions()
        self._fid = kinematics.frame_id("racket")

    def _racket(self, q, qd) -> RacketState:
        T, J = self.kin.fk_and_jacobian(np.asarray(q, float), self._fid)
        return RacketState.from_pose(T, J[:3] @ qd)

    def run(self, serve, seed: np.random.SeedSequence, *, ball: int = 0, record: bool = False,
            record_images_every: int = 0):
        """Play ``serve`` (a harness.sim.launcher.Serve). Returns (BallResult, BallRecord | None).

        record : keep everything for the session log; record_images_every : with a source that renders
        (vision), also keep the images of every N-th frame set (0: none)."""
        ss_source, ss_wam, ss_phase = seed.spawn(3)
        o, prof, policy, filt = self.options, self.profile, self.policy, self.filter
        rec = BallRecord() if record else None
        world = BallWorld(self.params, o.world)
        world.reset(serve.state)
        wam = SimulatedWam(self.kin, self.sim_options, seed=int(ss_wam.generate_state(1)[0]))
        self.source.reset(ss_source)
        filt.reset()
        policy.reset(q_ready=wam.read_state().q)
        late = _LateCommands(wam, o.plan_latency_s) if o.plan_latency_s > 0 else None
        frame_dt = 1.0 / prof.rate_hz
        t_frame = float(np.random.default_rng(ss_phase).uniform(0.0, frame_dt))
        pending: collections.deque = collections.deque()
        n_frames = n_positions = n_accepted = 0
        dt, dw = wam.dt_s, o.world.dt_s
        n_sub = max(int(round(dt / dw)), 1)
        truth = wam.true_state()
        q_prev = truth.q
        racket_prev = self._racket(truth.q, truth.qdot)
        closest = np.inf
        t_contact = None
        t = 0.0
        while True:
            while pending and pending[0][0] <= t + 1e-12:  # observations that have arrived by now
                obs = pending.popleft()[1]
                upd = filt.update(obs)
                n_positions += obs.position_m is not None
                n_accepted += bool(upd.accepted)
                if rec is not None:
                    rec.observations.append((obs, upd))
                    rec.filter_states.append((obs.t_s, filt.state()))
            if late is None:
                step = policy.step(t, filt.predict, wam)
            else:  # the step plans for t + latency from what arrived by t; its command reaches the robot then
                late.deliver(t)
                late.now_s = t
                step = policy.step(t + late.latency_s, filt.predict, late)
            if rec is not None and step.plan is not None:
                rec.plans.append(step.plan)
            samples = wam.advance_to(t + dt)
            q_true, qd_true = samples.q_true[-1], samples.qdot_true[-1]
            racket_next = self._racket(q_true, qd_true)
            capture = t_contact is None and policy.status not in (PolicyStatus.COMMITTED, PolicyStatus.DONE)
            for sub in range(n_sub):
                f0, f1 = sub / n_sub, (sub + 1) / n_sub
                ra, rb = lerp_racket(racket_prev, racket_next, f0), lerp_racket(racket_prev, racket_next, f1)
                s0, ta = world.state.copy(), world.t_s
                events = world.step(ra, rb)
                s1 = world.state
                closest = min(closest, float(np.linalg.norm(s1[:3] - rb.center_m)))
                if rec is not None:
                    rec.events.extend(events)
                if t_contact is None and any(e.kind == EventKind.RACKET for e in events):
                    t_contact = world.t_s
                while t_frame <= world.t_s + 1e-12:  # frame sets captured during this world step
                    if capture and not world.done:
                        w = (t_frame - ta) / dw
                        pos, vel = s0[:3] + w * (s1[:3] - s0[:3]), s0[3:6] + w * (s1[3:6] - s0[3:6])
                        q_f = q_prev + ((t_frame - t) / dt) * (q_true - q_prev)
                        obs = self.source.observe(n_frames, t_frame, pos, vel, q_f)
                        pending.append((t_frame + prof.latency_s, obs))
                        images = getattr(self.source, "last_images", None)
                        if rec is not None and record_images_every and images and n_frames % record_images_every == 0:
                            rec.images.append((t_frame, list(zip(self.source.rig.names, images))))
                        n_frames += 1
                    t_frame += frame_dt
                if world.done:
                    break
            if rec is not None:
                rec.truth_t_s.append(world.t_s)
                rec.truth_m.append(world.state[:3].copy())
                rec.robot_t_s.append(samples.t_s[-1])
                rec.q_reported.append(samples.q[-1].copy())
                rec.qdot_reported.append(samples.qdot[-1].copy())
                rec.q_true.append(q_true.copy())
                rec.q_command.append(samples.q_ref[-1].copy())
            racket_prev, q_prev = racket_next, q_true
            t += dt
            if ball_over(world, t, t_contact, o):
                break
        return self._result(ball, serve, world, policy, t_contact, closest, n_frames, n_positions, n_accepted), rec

    def _result(self, ball, serve, world, policy, t_contact, closest, n_frames, n_positions, n_accepted) -> BallResult:
        return ball_result(ball, serve, policy, world_summary(world, self.options.world.table, closest),
                           n_frames, n_positions, n_accepted)


def ball_over(world: BallWorld, t_s: float, t_contact_s: float | None, options: SessionOptions) -> bool:
    """Whether the ball's session ends at ball time ``t_s``: the world is done; hit, its return is
    classified or ``after_hit_s`` passed; unhit, ``max_flight_s`` passed or it is beyond ``past_robot_x_m``."""
    if world.done:
        return True
    if t_contact_s is not None:
        return classify_return(world.events, options.world.table) != "in_flight" or t_s > t_contact_s + options.after_hit_s
    return t_s > options.max_flight_s or world.state[0] < options.past_robot_x_m


def world_summary(world: BallWorld, table, closest_m: float) -> dict:
    """What the ball world knows of one ball (JSON-ready): ``contact_t_s`` / ``contact_m`` of the first racket
    contact (None: no contact), ``outcome`` (``classify_return`` of the events, None without a contact),
    ``landing_xy_m`` (the first table or floor bounce after the contact), ``closest_approach_m``."""
    contact = next((e for e in world.events if e.kind == EventKind.RACKET), None)
    landing = None
    if contact is not None:
        after = [e for e in world.events if e.t_s > contact.t_s and e.kind in (EventKind.TABLE, EventKind.FLOOR)]
        landing = [float(v) for v in after[0].position_m[:2]] if after else None
    return {"outcome": None if contact is None else str(classify_return(world.events, table)),
            "contact_t_s": None if contact is None else float(contact.t_s),
            "contact_m": None if contact is None else [float(v) for v in contact.position_m],
            "landing_xy_m": landing, "closest_approach_m": float(closest_m)}


def ball_result(ball: int, serve, policy, world: dict, n_frames: int, n_positions: int, n_accepted: int) -> BallResult:
    """The :class:`BallResult` of one ball from the policy (attempted, plans, reasons) and the world's
    :func:`world_summary` (in process, or as the live world process reports it). serve : needs
    ``speed_mps`` and ``spin_kind``."""
    plan = policy.plan
    if not policy.attempted:
        counts = {k: v for k, v in policy.reason_counts.items() if k != NO_PREDICTION}
        reason = "; ".join(f"{k} ({v}x)" for k, v in sorted(counts.items(), key=lambda kv: -kv[1]))
        outcome, reason = "no_attempt", reason or policy.reason or "no movement started"
    elif world["contact_t_s"] is None:
        outcome, reason = "no_hit", f"the racket missed the ball (closest approach {world['closest_approach_m'] * 100:.1f} cm)"
    else:
        outcome, reason = world["outcome"], ""
    return BallResult(
        ball=int(ball), outcome=str(outcome), success=outcome == "landed_in", attempted=bool(policy.attempted),
        reason=reason, n_frames=n_frames, n_positions=n_positions, n_accepted=n_accepted, n_plans=len(policy.plans),
        t_hit_planned_s=None if plan is None else float(plan.t_hit_s),
        hit_point_planned_m=None if plan is None else [float(v) for v in plan.ball_position_m],
        contact_t_s=world["contact_t_s"], contact_m=world["contact_m"], landing_xy_m=world["landing_xy_m"],
        closest_approach_m=float(world["closest_approach_m"]), serve_speed_mps=float(serve.speed_mps),
        spin_kind=str(serve.spin_kind), plan_failures=dict(policy.reason_counts))


def lerp_racket(a: RacketState, b: RacketState, f: float) -> RacketState:
    """The racket a fraction ``f`` of the way from ``a`` to ``b`` (within one control tick)."""
    if f <= 0.0:
        return a
    if f >= 1.0:
        return b
    return RacketState(a.center_m + f * (b.center_m - a.center_m), a.normal + f * (b.normal - a.normal),
                       a.velocity_mps + f * (b.velocity_mps - a.velocity_mps))
