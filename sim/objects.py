"""Scene primitives: planar surface patches (sampled afresh every scan), point scatterers (persistent), and
moving boxes that ride on a CA trajectory.

Why two kinds (docs/simulator.md): an imaging radar does not see the same point twice on an extended surface
(facades, car bodies, guard rails, ground): each scan returns detections at new random places on the surface,
so surfaces are `Patches` sampled uniformly per scan. Point-like scatterers (poles, signs, corners, rail posts)
persist at fixed positions with a per-scatterer detection probability: `Points`.

Detection source labels (truth.npz `label`): 0 static surface, 1 static point scatterer, 2 moving object,
3 clutter (false alarm), 4 ghost (multipath or the ghosts fault).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3

from .trajectory import Profile

STATIC_SURFACE, STATIC_POINT, MOVING, CLUTTER = 0, 1, 2, 3
GHOST = 4  # a multipath ghost (sim.multipath, sensor profiles) or a ghost fault (sim.faults)


@dataclass(frozen=True)
class Patches:
    """P planar rectangles {origin + a u + b v : a, b in [0, 1]}, u perpendicular to v.

    Attributes:
        origin, u, v: (P, 3) corner and edge vectors (metres, in the owner's frame).
        object_id: (P,) int id of the object the patch belongs to (a building, a car, a rail...).
        reflectivity: (P,) relative return density (1 for facades; lower for ground, higher for metal).
        opaque: (P,) bool, hides what is behind it (facades, vehicles); ground and rails are not opaque.
        two_sided: (P,) bool, visible from both sides; otherwise only from the side of normal = u x v.
    """

    origin: np.ndarray
    u: np.ndarray
    v: np.ndarray
    object_id: np.ndarray
    reflectivity: np.ndarray
    opaque: np.ndarray
    two_sided: np.ndarray

    def __len__(self) -> int:
        return len(self.origin)

    @property
    def normal(self) -> np.ndarray:
        n = np.cross(self.u, self.v)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    @property
    def area(self) -> np.ndarray:
        return np.linalg.norm(np.cross(self.u, self.v), axis=-1)

    @property
    def center(self) -> np.ndarray:
        return self.origin + 0.5 * (self.u + self.v)

    @property
    def half_diagonal(self) -> np.ndarray:
        return 0.5 * np.linalg.norm(self.u + self.v, axis=-1)

    def subset(self, idx) -> "Patches":
        return Patches(*(getattr(self, f)[idx] for f in _PATCH_FIELDS))

    def transformed(self, T: np.ndarray) -> "Patches":
        """The patches mapped by the rigid transform T (4, 4)."""
        C, r = T[:3, :3], T[:3, 3]
        return Patches(self.origin @ C.T + r, self.u @ C.T, self.v @ C.T, self.object_id, self.reflectivity,
                       self.opaque, self.two_sided)

    @staticmethod
    def concat(items) -> "Patches":
        items = [p for p in items if p is not None and len(p)]
        if not items:
            return empty_patches()
        return Patches(*(np.concatenate([getattr(p, f) for p in items]) for f in _PATCH_FIELDS))

    def sample(self, counts: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """counts (P,) points uniform on each patch -> (N, 3) points and (N,) patch indices."""
        idx = np.repeat(np.arange(len(self)), counts)
        ab = rng.random((idx.size, 2))
        return self.origin[idx] + ab[:, :1] * self.u[idx] + ab[:, 1:] * self.v[idx], idx


_PATCH_FIELDS = ("origin", "u", "v", "object_id", "reflectivity", "opaque", "two_sided")


def empty_patches() -> Patches:
    z3 = np.zeros((0, 3))
    return Patches(z3, z3, z3, np.zeros(0, int), np.zeros(0), np.zeros(0, bool), np.zeros(0, bool))


def rectangle(origin, u, v, object_id: int, reflectivity: float = 1.0, opaque: bool = True,
              two_sided: bool = False, max_size: float = 4.0) -> Patches:
    """One rectangle split into tiles no larger than max_size x max_size (keeps per-patch range ~constant)."""
    origin, u, v = (np.asarray(x, dtype=float) for x in (origin, u, v))
    # a side that is a whole number of tiles long (common: buildings span route points 1 m apart) gets that
    # many whatever its round-off, so the world does not depend on the last bit of the trajectory
    nu = max(int(np.ceil(np.linalg.norm(u) / max_size - 1e-9)), 1)
    nv = max(int(np.ceil(np.linalg.norm(v) / max_size - 1e-9)), 1)
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    i, j = i.ravel(), j.ravel()
    n = i.size
    o = origin + (i[:, None] / nu) * u + (j[:, None] / nv) * v
    return Patches(o, np.tile(u / nu, (n, 1)), np.tile(v / nv, (n, 1)), np.full(n, object_id, dtype=int),
                   np.full(n, float(reflectivity)), np.full(n, bool(opaque)), np.full(n, bool(two_sided)))


def box(T_world_box: np.ndarray, size, object_id: int, reflectivity: float = 1.0, opaque: bool = True,
        max_size: float = 4.0) -> Patches:
    """The four sides and the top of a box (length x, width y, height z; origin at the centre of its bottom
    face), outward-facing one-sided patches, mapped by T_world_box."""
    L, W, H = (float(s) for s in size)
    ex, ey, ez = np.array([L, 0, 0.0]), np.array([0, W, 0.0]), np.array([0, 0, H])
    c = np.array([-L / 2, -W / 2, 0.0])  # rear right bottom corner
    faces = [  # (origin, u, v) with u x v pointing outwards
        (c, ez, ey),                    # rear (-x)
        (c + ex, ey, ez),               # front (+x)
        (c, ex, ez),                    # right (-y)
        (c + ey, ez, ex),               # left (+y)
        (c + ez, ex, ey),               # top (+z)
    ]
    parts = [rectangle(o, u, v, object_id, reflectivity, opaque, False, max_size) for o, u, v in faces]
    return Patches.concat(parts).transformed(np.asarray(T_world_box, dtype=float))


@dataclass(frozen=True)
class Points:
    """N persistent point scatterers: p (N, 3), pd (N,) detection probability at short range, landmark_id (N,)."""

    p: np.ndarray
    pd: np.ndarray
    landmark_id: np.ndarray

    def __len__(self) -> int:
        return len(self.p)

    @staticmethod
    def concat(items) -> "Points":
        items = [p for p in items if p is not None and len(p)]
        if not items:
            return Points(np.zeros((0, 3)), np.zeros(0), np.zeros(0, int))
        return Points(np.concatenate([p.p for p in items]), np.concatenate([p.pd for p in items]),
                      np.concatenate([p.landmark_id for p in items]))


@dataclass(frozen=True)
class MovingBox:
    """A vehicle-sized box riding on a CA carrier trajectory with a linear time map.

    Pose: T_world_object(t) = T_world_carrier(tau(t)) T_carrier_object, tau(t) = tau0 + rate (t - t_on),
    present for t in [t_on, t_off]. With carrier = the ego profile, rate = 1 and tau0 = t_on + delta this is a
    lead vehicle delta seconds ahead on the same path; rate < 0 with a half-turn in T_carrier_object gives
    oncoming traffic in the other lane. The time map keeps the motion a rigid CA motion (velocities scale by
    `rate`), so point velocities are exact.
    """

    object_id: int
    size: tuple
    carrier: Profile
    tau0: float
    rate: float
    t_on: float
    t_off: float
    T_carrier_object: np.ndarray = field(default_factory=lambda: np.eye(4))
    reflectivity: float = 2.0

    def __post_init__(self):
        lo, hi = sorted((self.tau(self.t_on), self.tau(self.t_off)))
        if lo < -1e-9 or hi > self.carrier.duration + 1e-9:
            raise InputError(f"MovingBox {self.object_id}: carrier time {lo:.2f}..{hi:.2f} s leaves the carrier's"
                             f" 0..{self.carrier.duration:.2f} s")

    def tau(self, t):
        return self.tau0 + self.rate * (np.asarray(t, dtype=float) - self.t_on)

    @cached_property
    def body_patches(self) -> Patches:
        """The box's faces in the object frame (cached)."""
        return box(np.eye(4), self.size, self.object_id, self.reflectivity, opaque=True)

    def states(self, times: np.ndarray) -> "RigidStates":
        """Poses and world-frame velocities at `times` (M,); entries outside [t_on, t_off] are flagged absent
        (and NaN: only the present ones are computed, so a mover costs its presence, not the drive's length)."""
        times = np.asarray(times, dtype=float)
        present = (times >= self.t_on) & (times <= self.t_off)
        T_world_object = np.full((times.size, 4, 4), np.nan)  # absent rows: NaN (never to be used)
        v_origin, w_world = np.full((times.size, 3), np.nan), np.full((times.size, 3), np.nan)
        rows = np.flatnonzero(present)  # a carrier pose depends on its time alone: sample only these
        tau = np.clip(self.tau(times[rows]), 0.0, self.carrier.duration)
        order = np.argsort(tau, kind="stable")
        m = self.carrier.sample(tau[order])
        inv = np.empty_like(order)
        inv[order] = np.arange(order.size)
        T_world_carrier = se3.inverse(m.T_vehicle_world[inv])
        body = -m.varpi[inv]  # usual body twist [v; w] of T_world_carrier
        T_world_object[rows] = T_world_carrier @ self.T_carrier_object
        C = T_world_carrier[:, :3, :3]
        q = self.T_carrier_object[:3, 3]
        v_origin[rows] = self.rate * np.einsum("mij,mj->mi", C, body[:, :3] + np.cross(body[:, 3:], q))
        w_world[rows] = self.rate * np.einsum("mij,mj->mi", C, body[:, 3:])
        return RigidStates(T_world_object, v_origin, w_world, present)


@dataclass(frozen=True)
class RigidStates:
    """Rigid motion samples: T_world_object (M, 4, 4), velocity of the object origin and angular velocity, both
    in world coordinates (M, 3), and `present` (M,) bool. A point p_world moves with v + w x (p - origin)."""

    T_world_object: np.ndarray
    v_world: np.ndarray
    w_world: np.ndarray
    present: np.ndarray
