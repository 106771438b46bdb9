"""The map's surface model: planes found where they are, the covariance loose along and tight across them, the
isotropic term elsewhere; and what it is for, roll and pitch on resampled surfaces (estimator/surface.py)."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rodo import scenarios
from rodo.estimator.config import OdometryConfig
from rodo.estimator.lie import se3
from rodo.estimator.surface import surface_covariances
from rodo.validation.driver import run_sequence
from tests.strategies import rotation_vectors, vectors

SIG_N, SIG_T, SIG_ISO = 0.03, 0.1, 0.2


def _plane_points(rng, normal, centre, side=7, spacing=0.5, roughness=0.0):
    """side x side points of a jittered grid on the plane through `centre` with unit `normal`, shuffled."""
    u = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    grid = spacing * (np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2) - (side - 1) / 2)
    a, b = rng.permutation(grid + rng.uniform(-0.3, 0.3, grid.shape) * spacing).T
    n = len(a)
    return centre + a[:, None] * u + b[:, None] * v + roughness * rng.standard_normal((n, 1)) * normal


@given(phi=rotation_vectors("any"), centre=vectors(3, 50.0), seed=st.integers(0, 2**32 - 1))
def test_a_plane_gets_its_normal_tight_and_its_tangents_loose(phi, centre, seed):
    rng = np.random.default_rng(np.random.SeedSequence(seed))
    normal = se3.exp(np.r_[np.zeros(3), phi])[:3, :3] @ np.array([0.0, 0.0, 1.0])
    p = _plane_points(rng, normal, centre, roughness=0.005)
    cov, planar = surface_covariances(p[:10], p[10:], SIG_N, SIG_T, SIG_ISO, neighbours=10, radius=5.0)
    assert planar.all()
    for C in cov:
        w, V = np.linalg.eigh(C)
        np.testing.assert_allclose(w, [SIG_N**2, SIG_T**2, SIG_T**2], rtol=1e-9)
        assert abs(V[:, 0] @ normal) > 0.99  # the tight direction is the plane's normal


@given(seed=st.integers(0, 2**32 - 1))
def test_a_blob_an_edge_and_a_lonely_point_get_the_isotropic_term(seed):
    rng = np.random.default_rng(np.random.SeedSequence(seed))
    cube = np.stack(np.meshgrid(*[np.arange(3.0)] * 3), -1).reshape(-1, 3)
    blob = cube + 0.05 * rng.standard_normal(cube.shape)      # a volume, not a surface
    line = np.c_[rng.uniform(-2, 2, 20), 1e-3 * rng.standard_normal((20, 2))]  # a pole or an edge
    lonely = np.array([[100.0, 0.0, 0.0]])                    # nothing within the radius
    for p_new, p_map in ((blob[:5], blob[5:]), (line[:5], line[5:]), (lonely, blob)):
        cov, planar = surface_covariances(p_new, p_map, SIG_N, SIG_T, SIG_ISO, neighbours=27, radius=5.0)
        assert not planar.any()
        np.testing.assert_array_equal(cov, np.broadcast_to(SIG_ISO**2 * np.eye(3), cov.shape))


def test_neighbours_come_from_the_map_and_the_new_points_alike():
    rng = np.random.default_rng(np.random.SeedSequence(3))
    ground = _plane_points(rng, np.array([0.0, 0.0, 1.0]), np.zeros(3))
    alone = surface_covariances(ground[:1], np.zeros((0, 3)), SIG_N, SIG_T, SIG_ISO)[1]
    with_map = surface_covariances(ground[:1], ground[1:], SIG_N, SIG_T, SIG_ISO)[1]
    with_new = surface_covariances(ground, np.zeros((0, 3)), SIG_N, SIG_T, SIG_ISO)[1]
    assert not alone[0] and with_map[0] and with_new.all()
    assert surface_covariances(np.zeros((0, 3)), ground, SIG_N, SIG_T, SIG_ISO)[0].shape == (0, 3, 3)


@pytest.fixture(scope="module")
def stiff_prior_drive():
    """20 s drawn from the CA prior with vehicle-like Qc (roll and pitch jerk 1e-7): the motion model is exact."""
    qc = [1e-2, 1e-4, 1e-4, 1e-7, 1e-7, 1e-5]
    seq, truth = scenarios.get("prior_ca").simulate(1, 20.0, qc=qc)
    return seq, truth, qc


def _roll_pitch_error(seq, truth, qc, **map_options):
    config = OdometryConfig.from_dict({"model": "ca-polar", "noise": {"qc_ca": qc},
                                       "vehicle": {"sigma_roll_rate": 0.0, "sigma_pitch_rate": 0.0},
                                       "map": map_options})
    T = run_sequence(seq, config).columns["T_vehicle_world"]
    err = np.array([se3.log(a @ se3.inverse(b))[3:5] for a, b in zip(T, truth["T_vehicle_world"])])
    return np.abs(err).max()


def test_the_surface_model_holds_roll_and_pitch_where_point_to_point_pairs_let_them_wander(stiff_prior_drive):
    """At the true Qc, without the vehicle's roll/pitch terms, the paper's isotropic map sigma lets roll wander
    by 0.22 rad over this drive (0.04 with the surface model): ground and facade pairs resampled along their
    surfaces count as roll information they do not hold; the surface model keeps only the across-surface part.
    Not a cure: over seeds 2-7 of this set-up it halves the median KITTI error (7.0 -> 3.3 %) and is worse on
    one seed of six (docs/consistency.md, "Roll and pitch on resampled surfaces")."""
    seq, truth, qc = stiff_prior_drive
    isotropic = _roll_pitch_error(seq, truth, qc)
    surface = _roll_pitch_error(seq, truth, qc, surface_normal_sigma=0.03)
    assert isotropic > 0.1
    assert surface < 0.5 * isotropic
