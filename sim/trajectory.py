"""Vehicle trajectories from constant-acceleration segments, integrated exactly on SE(3).

Model (the paper's CA nominal model, eq. 13-16, with piecewise-constant varpi_dot): the state pose is
T = T_vehicle_world with dT/dt = varpi^ T, varpi = [nu; omega] (translation first). Inside segment i,
starting at time t_i, varpi(t) = varpi_i + (t - t_i) varpi_dot_i exactly, and varpi is continuous across
segments (piecewise linear). Vehicle-like motion: no lateral slip, nu = [-speed, 0, 0] always.

Integration: 4th-order Magnus per sub-step of at most `max_step` seconds. For A(t) = hat(a + tau w) linear in
time the two-point Gauss-Legendre Magnus step reduces to
    Omega = h a_mid + h^3/12 curlyhat(w) a_mid,       T(t + h) = exp(Omega^) T(t),
whose local error is O(h^5) (checked against DOP853 at rtol 1e-13 in
tests/sim/test_trajectory.py::test_magnus_matches_dop853).

The vehicle quantities relate to the state as in docs/conventions.md: varpi = -[v; w], varpi_dot = -[a; alpha]
with v, w, a, alpha in the vehicle frame (x forward, y left, z up).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rodo.estimator.errors import InputError, check_finite
from rodo.estimator.lie import se3

MAX_STEP = 0.0025  # s; Magnus sub-step: global error at DOP853's own floor (~1e-12, see the tests); 0.005 s reached
# 5e-12 where the vehicle turns at 2 rad/s
CHECKPOINT_EVERY = 32  # grid steps between the poses a Profile keeps (an hour at MAX_STEP: 45,000 poses, 5.8 MB)


@dataclass(frozen=True)
class Segment:
    """A constant-acceleration piece of a vehicle trajectory.

    Attributes:
        duration: seconds, > 0.
        accel: forward acceleration, m/s^2 (body x).
        roll_acc, pitch_acc, yaw_acc: angular accelerations about the body x, y (left), z (up) axes,
            rad/s^2, right-handed: yaw_acc > 0 turns left, pitch_acc > 0 pitches the nose down.
    """

    duration: float
    accel: float = 0.0
    roll_acc: float = 0.0
    pitch_acc: float = 0.0
    yaw_acc: float = 0.0

    @property
    def varpi_dot(self) -> np.ndarray:
        """(6,) body acceleration in the paper's convention, -[a, 0, 0, alpha]."""
        return -np.array([self.accel, 0.0, 0.0, self.roll_acc, self.pitch_acc, self.yaw_acc])


@dataclass(frozen=True)
class Motion:
    """Samples of a trajectory: t (M,), T_vehicle_world (M, 4, 4), varpi (M, 6), varpi_dot (M, 6)."""

    t: np.ndarray
    T_vehicle_world: np.ndarray
    varpi: np.ndarray
    varpi_dot: np.ndarray

    @property
    def T_world_vehicle(self) -> np.ndarray:
        return se3.inverse(self.T_vehicle_world)

    @property
    def speed(self) -> np.ndarray:
        return -self.varpi[:, 0]


class Profile:
    """Initial state + CA segments: T_vehicle_world(0), varpi(0) and a sequence of `Segment`s.

    Args:
        segments: the segments, in order (durations > 0).
        speed0: initial forward speed, m/s (>= 0); the initial angular rate is zero.
        T_vehicle_world0: (4, 4) initial pose (default identity).
    """

    def __init__(self, segments, speed0: float = 0.0, T_vehicle_world0: np.ndarray | None = None):
        self.segments = tuple(segments)
        if not self.segments:
            raise InputError("segments: need at least one segment")
        durations = np.array([s.duration for s in self.segments], dtype=float)
        if not np.all(np.isfinite(durations)) or np.any(durations <= 0):
            raise InputError("segments: every duration must be finite and > 0")
        if not np.isfinite(speed0) or speed0 < 0:
            raise InputError(f"speed0: must be finite and >= 0, got {speed0}")
        self.T0 = np.eye(4) if T_vehicle_world0 is None else check_finite("T_vehicle_world0", T_vehicle_world0,
                                                                          (4, 4)).copy()
        self.t_start = np.concatenate([[0.0], np.cumsum(durations)])  # (S + 1,) segment boundaries
        self.varpi_dot_seg = np.array([s.varpi_dot for s in self.segments])  # (S, 6)
        varpi0 = np.array([-float(speed0), 0, 0, 0, 0, 0])
        steps = durations[:, None] * self.varpi_dot_seg
        varpi_seg = varpi0 + np.concatenate([np.zeros((1, 6)), np.cumsum(steps, axis=0)])  # (S + 1, 6)
        # round-off of the running sum (~1e-15) must not turn a standstill into a crawl or a reversal
        varpi_seg[np.abs(varpi_seg) < 1e-12] = 0.0
        self.varpi_seg = varpi_seg
        self._grids: dict = {}  # max_step -> the integrated grid (`_grid`)

    @property
    def duration(self) -> float:
        return float(self.t_start[-1])

    def _segment_of(self, t: np.ndarray) -> np.ndarray:
        return np.clip(np.searchsorted(self.t_start, t, side="right") - 1, 0, len(self.segments) - 1)

    def twist(self, t) -> tuple[np.ndarray, np.ndarray]:
        """varpi(t), varpi_dot(t) for times (M,) -> (M, 6), (M, 6); exact piecewise-linear varpi."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        i = self._segment_of(t)
        varpi_dot = self.varpi_dot_seg[i]
        return self.varpi_seg[i] + (t - self.t_start[i])[:, None] * varpi_dot, varpi_dot

    def speed_range(self) -> tuple[float, float]:
        """Minimum and maximum forward speed (speed is piecewise linear: the extremes sit at boundaries)."""
        s = -self.varpi_seg[:, 0]
        return float(s.min()), float(s.max())

    def path_length(self, t_end: float | None = None) -> float:
        """Distance driven in [0, t_end] (the integral of the piecewise-linear speed)."""
        t_end = self.duration if t_end is None else min(float(t_end), self.duration)
        knots = np.concatenate([self.t_start[self.t_start < t_end], [t_end]])
        speed = -self.twist(knots)[0][:, 0]
        return float(np.sum(0.5 * (speed[1:] + speed[:-1]) * np.diff(knots)))

    def sample(self, times, max_step: float = MAX_STEP) -> Motion:
        """Integrate dT/dt = varpi^ T from 0 and return the motion at `times` (non-decreasing, in [0, duration]).

        The profile is integrated once (per max_step, cached) on a fixed grid: each segment split into equal
        sub-steps no longer than max_step, so no step straddles a segment boundary and every step sees a linear
        varpi, where the 4th-order Magnus step above applies; the pose is kept every CHECKPOINT_EVERY steps. A
        time's pose is its checkpoint's, carried by the grid steps after it and one last partial step. So the
        pose at t depends on t alone, not on the other times asked for (a mover's states over the scans where it
        is present equal those over the whole drive), and sampling costs O(len(times)) after one pass over the
        profile: an hour-long drive's few hundred movers no longer integrate it each.
        Checked by tests/sim/test_trajectory.py::test_magnus_matches_dop853, ::test_a_pose_depends_on_its_time_alone.
        """
        times = check_finite("times", np.atleast_1d(times), (-1,))
        if times.ndim != 1 or np.any(np.diff(times) < 0):
            raise InputError("times: must be a non-decreasing 1-D array")
        if times.size and (times[0] < 0 or times[-1] > self.duration + 1e-9):
            raise InputError(f"times: must lie in [0, {self.duration:.3f}] s, got [{times[0]}, {times[-1]}]")
        n_sub, h, first, checkpoints = self._grid(float(max_step))
        i = self._segment_of(times)
        j = np.clip(np.floor((times - self.t_start[i]) / h[i]).astype(np.int64), 0, n_sub[i] - 1)
        c = j // CHECKPOINT_EVERY
        T = checkpoints[first[i] + c]
        for r in range(CHECKPOINT_EVERY - 1):  # the grid steps from the checkpoint to the step containing t
            sel = np.flatnonzero(j - c * CHECKPOINT_EVERY > r)
            if not sel.size:
                break
            k = c[sel] * CHECKPOINT_EVERY + r
            T[sel] = self._steps(i[sel], self.t_start[i[sel]] + k * h[i[sel]], h[i[sel]]) @ T[sel]
        t_grid = self.t_start[i] + j * h[i]
        T = self._steps(i, t_grid, times - t_grid) @ T  # the last, partial step (zero length on the grid)
        varpi, varpi_dot = self.twist(times)
        # at a segment boundary report the acceleration of the segment that starts there
        return Motion(times.copy(), T, varpi, varpi_dot)

    def _steps(self, seg: np.ndarray, ta: np.ndarray, h: np.ndarray) -> np.ndarray:
        """exp(Omega^) of the Magnus steps of length h from ta inside segments seg: (n, 4, 4)."""
        w = self.varpi_dot_seg[seg]
        a_mid = self.varpi_seg[seg] + (ta + 0.5 * h - self.t_start[seg])[:, None] * w
        omega = h[:, None] * a_mid + (h**3 / 12.0)[:, None] * np.einsum("nij,nj->ni", se3.curlyhat(w), a_mid)
        return se3.exp(omega)

    def _grid(self, max_step: float):
        """(sub-steps per segment, their length, each segment's first checkpoint, the checkpoint poses)."""
        if max_step in self._grids:
            return self._grids[max_step]
        if not (np.isfinite(max_step) and max_step > 0):
            raise InputError(f"max_step: must be a positive number of seconds, got {max_step}")
        durations = np.diff(self.t_start)
        n_sub = np.maximum(np.ceil(durations / max_step).astype(np.int64), 1)
        h = durations / n_sub
        per_segment = (n_sub - 1) // CHECKPOINT_EVERY + 1  # checkpoints at steps 0, C, 2C, ... of a segment
        first = np.concatenate([[0], np.cumsum(per_segment)[:-1]])
        checkpoints = np.empty((int(per_segment.sum()), 4, 4))
        T = self.T0
        for s in range(len(n_sub)):
            k = np.arange(n_sub[s])
            steps = self._steps(np.full(n_sub[s], s), self.t_start[s] + k * h[s], np.full(n_sub[s], h[s]))
            for idx in range(n_sub[s]):
                if idx % CHECKPOINT_EVERY == 0:
                    checkpoints[first[s] + idx // CHECKPOINT_EVERY] = T
                T = steps[idx] @ T
        self._grids[max_step] = (n_sub, h, first, checkpoints)
        return self._grids[max_step]


@dataclass(frozen=True)
class Route:
    """The driven path as a polyline, uniform in arc length: s (N,), p_world (N, 3), heading (N,), t (N,).

    heading is the yaw of the vehicle's forward axis in the world xy-plane (rad, CCW from +x).
    """

    s: np.ndarray
    p_world: np.ndarray
    heading: np.ndarray
    t: np.ndarray

    @property
    def length(self) -> float:
        return float(self.s[-1]) if self.s.size else 0.0

    def left(self) -> np.ndarray:
        """(N, 3) horizontal unit vectors to the left of the route."""
        return np.stack([-np.sin(self.heading), np.cos(self.heading), np.zeros_like(self.heading)], axis=-1)

    def forward(self) -> np.ndarray:
        """(N, 3) horizontal unit vectors along the route."""
        return np.stack([np.cos(self.heading), np.sin(self.heading), np.zeros_like(self.heading)], axis=-1)


def route_of(profile: Profile, spacing: float = 1.0, dt: float = 0.05) -> Route:
    """The vehicle path of `profile` resampled every `spacing` metres of arc length (standstills collapse)."""
    t = np.arange(0.0, profile.duration + 0.5 * dt, dt)
    t[-1] = min(t[-1], profile.duration)
    m = profile.sample(t)
    T_world_vehicle = m.T_world_vehicle
    p = T_world_vehicle[:, :3, 3]
    fwd = T_world_vehicle[:, :3, 0]
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    keep = np.concatenate([[True], np.diff(s) > 1e-9])
    s, p, fwd, t = s[keep], p[keep], fwd[keep], t[keep]
    s_new = np.arange(0.0, s[-1] + 1e-9, spacing) if s[-1] > 0 else np.zeros(1)
    p_new = np.stack([np.interp(s_new, s, p[:, i]) for i in range(3)], axis=-1)
    heading = np.unwrap(np.arctan2(fwd[:, 1], fwd[:, 0]))
    return Route(s_new, p_new, np.interp(s_new, s, heading), np.interp(s_new, s, t))


class ProfileBuilder:
    """Builds CA segments by targets: `add(duration, speed=..., yaw_rate=..., pitch_rate=..., roll_rate=...)`
    picks the constant accelerations that reach the targets at the segment's end (unset: keep the rate).

    Rates are the usual body rates (yaw_rate > 0 turns left); the builder tracks them exactly."""

    def __init__(self, speed0: float = 0.0):
        self.speed0 = float(speed0)
        self.speed = float(speed0)
        self.rates = np.zeros(3)  # roll, pitch, yaw rates, rad/s
        self.segments: list[Segment] = []

    @property
    def duration(self) -> float:
        return float(sum(s.duration for s in self.segments))

    def add(self, duration: float, speed: float | None = None, roll_rate: float | None = None,
            pitch_rate: float | None = None, yaw_rate: float | None = None) -> "ProfileBuilder":
        if duration <= 0:
            raise InputError(f"duration: must be > 0, got {duration}")
        target = [roll_rate, pitch_rate, yaw_rate]
        acc = 0.0 if speed is None else (max(float(speed), 0.0) - self.speed) / duration
        ang = [0.0 if r is None else (float(r) - self.rates[i]) / duration for i, r in enumerate(target)]
        self.segments.append(Segment(float(duration), acc, *ang))
        self.speed = self.speed + acc * duration if speed is None else max(float(speed), 0.0)
        self.rates = self.rates + np.array(ang) * duration
        return self

    def turn(self, angle: float, radius: float, ramp: float = 1.5) -> "ProfileBuilder":
        """A turn by `angle` rad (> 0 left) at the current speed: yaw rate ramps in, holds, ramps out.
        A turn by 0 adds nothing."""
        if angle == 0:
            return self
        v = max(self.speed, 1.0)
        rate = np.sign(angle) * v / radius
        hold = abs(angle) / abs(rate) - ramp  # ramps contribute rate * ramp / 2 each
        if hold < 0:  # short turn: triangular rate profile
            ramp = np.sqrt(abs(angle) * ramp / abs(rate))
            rate = angle / ramp
            hold = 0.0
        self.add(ramp, yaw_rate=rate)
        if hold > 0:
            self.add(hold)
        return self.add(ramp, yaw_rate=0.0)

    def build(self, T_vehicle_world0: np.ndarray | None = None) -> Profile:
        return Profile(self.segments, self.speed0, T_vehicle_world0)


# ---------------------------------------------------------------------------------------------- profiles
# Each profile draws its segments from `rng` until `duration` is covered (so a longer duration extends the
# same draw), starts at the identity pose and never drives backwards (speed targets are clipped at 0).

KMH = 1.0 / 3.6


def _bump(b: ProfileBuilder, rng: np.random.Generator, axis: str, amplitude: float) -> None:
    """A small pitch or roll oscillation (rate up, reverse, back to zero) that leaves the angle unchanged."""
    r = rng.uniform(-amplitude, amplitude)
    b.add(0.5, **{axis: r}).add(1.0, **{axis: -r}).add(0.5, **{axis: 0.0})


def city(rng: np.random.Generator, duration: float) -> Profile:
    """City driving: 0-50 km/h, 90 deg turns at intersections (slowing first), stops, small pitch/roll bumps."""
    b = ProfileBuilder(0.0)
    b.add(rng.uniform(3.0, 5.0), speed=rng.uniform(25, 50) * KMH)
    while b.duration < duration:
        cruise = rng.uniform(60.0, 140.0) / max(b.speed, 1.0)
        for _ in range(2):
            b.add(cruise / 2, speed=rng.uniform(25, 50) * KMH)
            _bump(b, rng, "pitch_rate", 0.02)
            _bump(b, rng, "roll_rate", 0.01)
        event = rng.uniform()
        if event < 0.65:  # intersection: slow, turn, speed up
            b.add(3.0, speed=rng.uniform(12, 20) * KMH)
            b.turn(rng.choice([-1.0, 1.0]) * np.pi / 2 * rng.uniform(0.9, 1.0), rng.uniform(9.0, 14.0))
            b.add(3.0, speed=rng.uniform(30, 50) * KMH)
        elif event < 0.85:  # stop at a light
            b.add(max(b.speed / 2.0, 1.0), speed=0.0)
            b.add(rng.uniform(2.0, 6.0))
            b.add(rng.uniform(4.0, 6.0), speed=rng.uniform(30, 50) * KMH)
        else:  # gentle bend
            b.turn(rng.uniform(-0.4, 0.4), rng.uniform(60.0, 120.0))
    return b.build()


def highway(rng: np.random.Generator, duration: float) -> Profile:
    """Highway: 80-130 km/h, gentle curves (radius 600-1500 m), lane changes (about 3.5 m in ~4 s)."""
    b = ProfileBuilder(rng.uniform(90, 120) * KMH)
    while b.duration < duration:
        b.add(rng.uniform(4.0, 10.0), speed=rng.uniform(80, 130) * KMH)
        event = rng.uniform()
        if event < 0.4:
            b.turn(rng.uniform(-0.25, 0.25), rng.uniform(600.0, 1500.0), ramp=4.0)
        elif event < 0.75:
            rate = np.sign(rng.uniform(-1, 1)) * 1.75 / (b.speed * 1.0)  # lateral ~ 2 rate tau^2 v = 3.5 m
            for target in (rate, 0.0, -rate, 0.0):
                b.add(1.0, yaw_rate=target)
        else:
            _bump(b, rng, "pitch_rate", 0.01)
    return b.build()


def hills(rng: np.random.Generator, duration: float) -> Profile:
    """Hills: 40-70 km/h, grade changes of 3-8 % held for 100-250 m (several metres of height), gentle
    curves only on level road."""
    b = ProfileBuilder(rng.uniform(40, 60) * KMH)
    climb = rng.choice([-1.0, 1.0])
    while b.duration < duration:
        b.add(rng.uniform(2.0, 4.0), speed=rng.uniform(40, 70) * KMH)
        grade = climb * rng.uniform(0.03, 0.08)
        climb = -climb
        tau = 2.0
        b.add(tau, pitch_rate=-grade / tau).add(tau, pitch_rate=0.0)  # pitch angle -grade (nose up if > 0)
        b.add(rng.uniform(100.0, 250.0) / b.speed)
        b.add(tau, pitch_rate=grade / tau).add(tau, pitch_rate=0.0)  # back to level
        if rng.uniform() < 0.5:
            b.turn(rng.uniform(-0.5, 0.5), rng.uniform(80.0, 200.0))
    return b.build()


def stop_and_go(rng: np.random.Generator, duration: float) -> Profile:
    """Stop-and-go traffic: accelerate to 10-35 km/h, roll briefly, brake to a standstill of 1.5-5 s."""
    b = ProfileBuilder(0.0)
    b.add(rng.uniform(0.5, 1.5))  # standing at the start
    while b.duration < duration:
        v = rng.uniform(10, 35) * KMH
        b.add(v / rng.uniform(1.0, 2.0), speed=v)
        b.add(rng.uniform(1.0, 6.0))
        if rng.uniform() < 0.3:
            b.turn(rng.uniform(-0.6, 0.6), rng.uniform(20.0, 60.0))
        b.add(b.speed / rng.uniform(1.0, 2.5), speed=0.0)
        b.add(rng.uniform(1.5, 5.0))
    return b.build()


def crawl(rng: np.random.Generator, duration: float, v_min: float = 2.0, v_max: float = 4.0) -> Profile:
    """Slow traffic that never stops: speed between v_min and v_max (used behind a close lead vehicle)."""
    b = ProfileBuilder(rng.uniform(v_min, v_max))
    while b.duration < duration:
        b.add(rng.uniform(2.0, 5.0), speed=rng.uniform(v_min, v_max))
        if rng.uniform() < 0.2:
            b.turn(rng.uniform(-0.3, 0.3), rng.uniform(30.0, 60.0))
    return b.build()


def yaw_accel(rng: np.random.Generator, duration: float, speed: float = 10.0,
              yaw_acc: float = 0.05) -> Profile:
    """The paper's Fig. 1 manoeuvre: constant forward speed and pure yaw acceleration (varpi_dot = [0,...,
    -yaw_acc]) from zero yaw rate. `rng` is unused (kept for the common profile signature)."""
    return Profile([Segment(float(duration), yaw_acc=yaw_acc)], speed0=speed)
