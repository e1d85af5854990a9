"""The peers' adapters: each peer's own convention turned into magbench's ``(T, h)``."""

import importlib.util

import numpy as np
import pytest

from magbench.core.geometry import fibonacci_sphere
from magbench.core.metrics import accuracy_cost
from magbench.studies import peers
from tests.conftest import dataset


def test_normalise_gives_unit_mean_norm():
    d = dataset(seed=4)
    T = peers._normalise(3.0 * d.T, d.h, d.y)
    m = np.linalg.solve(T, (d.y - d.h).T)
    assert np.mean(np.linalg.norm(m, axis=0)) == pytest.approx(1.0)


@pytest.mark.skipif(importlib.util.find_spec("magcal") is None, reason="peer magcal not installed")
def test_magcal_convention_is_converted():
    # magcal takes the sample mean as the centre, exact only for symmetric directions: use
    # antipodal pairs so that only our conversion of its T^-1 convention is under test.
    rng = np.random.default_rng(5)
    m = fibonacci_sphere(100)
    m = np.vstack([m, -m])
    T_true = np.eye(3) * 1.1 + rng.uniform(-0.05, 0.05, (3, 3))
    h_true = rng.uniform(-0.05, 0.05, 3)
    T, h = peers._magcal_ellipsoid(m @ T_true.T + h_true)
    assert accuracy_cost(T, h, T_true, h_true)[0] < 1e-9


@pytest.mark.skipif(importlib.util.find_spec("navlib") is None, reason="peer navlib not installed")
@pytest.mark.parametrize("name", [n for n in peers.PEER_FITS if n.startswith("navlib.")
                                  and not peers.needs_gyro(n)])
def test_every_navlib_adapter_gives_what_navlib_itself_outputs(name):
    """The adapter is what a user of navlib gets: its own calibrated field, up to scale."""
    import navlib.cal.cal_mag as cal_mag

    rng = np.random.default_rng(6)
    m = fibonacci_sphere(400)
    T_true = np.diag([1.2, 0.9, 1.05]) + rng.uniform(-0.03, 0.03, (3, 3))
    y = m @ T_true.T + np.array([0.4, -0.3, 0.2])
    T, h = peers.fit_peer(name, y)
    fn = getattr(cal_mag, name.removeprefix("navlib."))
    args = (y, np.array([1.0, 0.0, 0.0])) if "twostep" in name else (y,)
    theirs = np.asarray(fn(*args)[-1], dtype=float)
    theirs = theirs.T if theirs.shape[0] == 3 and theirs.shape[1] != 3 else theirs
    ours = np.linalg.solve(T, (y - h).T).T
    scale = np.linalg.norm(theirs, axis=1).mean() / np.linalg.norm(ours, axis=1).mean()
    np.testing.assert_allclose(scale * ours, theirs, atol=1e-6 * scale)


@pytest.mark.skipif(importlib.util.find_spec("navlib") is None, reason="peer navlib not installed")
@pytest.mark.parametrize("name", ["navlib.cal_mag_magyc_ls", "navlib.cal_mag_magyc_nls"])
def test_magyc_adapters_give_what_navlib_itself_outputs(name):
    """navlib's MAGYC corrected field is soft_iron^-1 (y - hard_iron): the adapter's T."""
    import navlib.cal.cal_mag as cal_mag

    from magbench.sources.trajectory import simulate

    traj = simulate(np.random.default_rng(2), T=np.diag([1.1, 0.95, 1.0]),
                    h=np.array([0.1, -0.2, 0.05]), duration_s=8.0)
    T, h = peers.fit_peer(name, traj.y, angular_rate=traj.angular_rate, time=traj.t)
    out = getattr(cal_mag, name.removeprefix("navlib."))(traj.y, traj.angular_rate, traj.t)
    theirs = np.asarray(out[2 if name.endswith("_ls") else 3], dtype=float)
    ours = np.linalg.solve(T, (traj.y - h).T).T
    scale = np.linalg.norm(theirs, axis=1).mean() / np.linalg.norm(ours, axis=1).mean()
    np.testing.assert_allclose(scale * ours, theirs, atol=1e-9)


def test_available_peers_lists_only_installed_packages():
    found = peers.available_peers()
    assert all(importlib.util.find_spec(peers.PEER_FITS[n][0]) is not None for n in found)
