"""The shortcuts that make a recording cheaper give the very numbers of the plain computation (issue 27).

The rotation kernels are read by compare as well as by the lock-step loop, and a bag must stay the
same recording: each shortcut is checked bit for bit against the formulation it replaced.
"""

import numpy as np
import pytest

from sofia_ros import mount
from sofia_ros.rotation_kernels import compose_quaternions, matrices_from_quaternions, quaternion_from_matrix


def stacked_composition(p, q):
    """compose_quaternions as np.stack of its four expressions (eq. B.25)."""
    px, py, pz, pw = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    qx, qy, qz, qw = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([pw * qx + qw * px + (py * qz - pz * qy), pw * qy + qw * py + (pz * qx - px * qz),
                     pw * qz + qw * pz + (px * qy - py * qx), pw * qw - px * qx - py * qy - pz * qz], axis=-1)


def stacked_matrices(quaternions):
    """matrices_from_quaternions as np.stack of its nine expressions."""
    x, y, z, w = quaternions[..., 0], quaternions[..., 1], quaternions[..., 2], quaternions[..., 3]
    x2, y2, z2, w2 = x * x, y * y, z * z, w * w
    xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
    return np.stack([x2 - y2 - z2 + w2, 2 * (xy - zw), 2 * (xz + yw), 2 * (xy + zw), -x2 + y2 - z2 + w2,
                     2 * (yz - xw), 2 * (xz - yw), 2 * (yz + xw), -x2 - y2 + z2 + w2], axis=-1).reshape(*x.shape, 3, 3)


@pytest.mark.parametrize('p_shape, q_shape', [((4,), (4,)), ((5, 4), (5, 4)), ((12, 4), (12, 4)), ((3, 4), (4,)),
                                              ((4,), (2, 3, 4))])
def test_kernels_give_the_bits_of_the_stacked_expressions(p_shape, q_shape):
    rng = np.random.default_rng(27)
    # Magnitudes over 16 decades, where a reordered sum would round differently.
    p = rng.normal(size=p_shape) * 10.0 ** rng.integers(-8, 8, size=p_shape)
    q = rng.normal(size=q_shape)
    composed = compose_quaternions(p, q)
    assert composed.shape == stacked_composition(p, q).shape
    assert composed.tobytes() == stacked_composition(p, q).tobytes()
    assert matrices_from_quaternions(p).tobytes() == stacked_matrices(p).tobytes()


def test_shepperd_branch_is_the_first_largest_as_argmax_chose_it():
    """Rotations by pi about x, y, z and none: each branch of quaternion_from_matrix, ties to the first."""
    for matrix in (np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, 1.0, -1.0]), np.diag([-1.0, -1.0, 1.0]), np.eye(3)):
        quaternion = quaternion_from_matrix(matrix)
        assert np.isclose(abs(quaternion[np.argmax(np.abs(quaternion))]), 1.0)
        assert np.array_equal(matrices_from_quaternions(quaternion), matrix)


def test_the_plants_kept_matrices_are_those_computed_afresh(monkeypatch):
    """The plant computes the cradle again only after a coarse-drive move and the Earth's turn once a tick."""
    from sofia_ros.campaigns.alignment import default_scenario
    from sofia_ros.sim.plant import PlantCore

    plant = PlantCore(default_scenario(), {'earth_rotation': {'rate_deg_per_h': 15.04}})
    calls, hrf_from_irf_dcm = [], mount.hrf_from_irf_dcm
    monkeypatch.setattr(mount, 'hrf_from_irf_dcm', lambda *args: calls.append(args) or hrf_from_irf_dcm(*args))
    plant.tick(200_000_000)
    assert len(calls) == 1  # the telescope's move and the specific force share one A_HRF,IRF
    plant.cd_target_deg = plant.elevation_deg + 1.0
    for stamp_ns in (400_000_000, 600_000_000):
        plant.tick(stamp_ns)
        fresh = mount.icrf_from_abrf_dcm(plant.elevation_deg) @ mount.abrf_from_hrf_dcm(plant.heading_deg)
        assert plant._cradle_from_hrf().tobytes() == fresh.tobytes()
    assert len(calls) == 3


def test_a_camera_without_hooks_keeps_its_mounting_while_the_elevation_holds(monkeypatch):
    """An imager without plug-in hooks computes A_CAM,TARF again only when the elevation changes, and its frames are
    those of a camera that computes it for each one."""
    import datetime as dt

    from sofia_ros.sensors import imager_model
    from sofia_ros.sky import WACO_2004_SITE

    scene = imager_model.Scene(WACO_2004_SITE, dt.datetime(2004, 9, 3, 4, 32, 51, tzinfo=dt.timezone.utc))
    effects = {'focal_plane_flexure': {}, 'imager_boresight_offset': {}}
    kept, fresh = (imager_model.ImagerTruth('ffi', effects, scene, exposure_s=2.0) for _ in range(2))
    calls, camera_from_tarf_dcm = [], imager_model.camera_from_tarf_dcm
    monkeypatch.setattr(imager_model, 'camera_from_tarf_dcm',
                        lambda *args: calls.append(args) or camera_from_tarf_dcm(*args))
    for elapsed_s, elevation_deg in ((0.0, 31.7), (2.0, 31.7), (4.0, 35.0), (6.0, 35.0)):
        frame = kept.centroids(elapsed_s, np.eye(3), elevation_deg)
        fresh._mounting_at = (None, None)
        assert frame and frame == fresh.centroids(elapsed_s, np.eye(3), elevation_deg)  # stars near the zenith
    assert len(calls) == 2 + 4  # the kept camera's two elevations, the fresh one's four frames
