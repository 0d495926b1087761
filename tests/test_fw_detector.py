"""tipbot_fw.cores.detector: the folded one-matrix step equals the equations; the detector converges."""

import numpy as np

import fw_support as S
from tipbot_fw.cores.detector import N_FIXED, fold, fold_full, reference_step
from tipbot_fw.gains import load_gains
from tipbot_fw.vocabulary import ACTUATED_INPUTS
from conftest import PHYSICAL_GAINS, gains_path

ACT = ACTUATED_INPUTS


def folded_step(M, y1_used, xt, w_prev, u, y0, y1):
    v = np.concatenate([xt, w_prev[ACT], u[ACT], y0, y1[y1_used]])
    z = M.dot(v)
    return z[:10], z[10:14], z[14:18]


def check_against_reference(g, rng, a=1.0, n=50):
    """The folded matrix against reference_step plus the low-pass written out."""
    M, used = fold(g, a)
    full = fold_full(g, a)
    Kw = g.K_w
    for _ in range(n):
        xt, y0, y1 = (rng.normal(0, 0.1, 10) for _ in range(3))
        u = rng.uniform(-7.6, 7.6, 5)
        w_prev = rng.uniform(-2, 2, 5)
        u[2] = w_prev[2] = 0.0
        xt1, w_hat, u1 = reference_step(g, xt, u, y0, y1)
        w_bar = w_prev + a * (w_hat - w_prev)
        u1 = u1 + Kw.dot(w_hat) - Kw.dot(w_bar)         # the law with the low-passed estimate
        z_full = full.dot(np.concatenate([xt, w_prev[ACT], u[ACT], y0, y1]))
        np.testing.assert_allclose(z_full, np.concatenate([xt1, w_bar[ACT], u1[ACT]]), rtol=1e-12, atol=1e-12)
        fx, fw, fu = folded_step(M, used, xt, w_prev, u, y0, y1)
        scale = max(1.0, np.abs(u1).max())
        np.testing.assert_allclose(fx, xt1, rtol=0, atol=1e-9)
        np.testing.assert_allclose(fw, w_bar[ACT], rtol=0, atol=1e-9)
        np.testing.assert_allclose(fu, u1[ACT], rtol=0, atol=1e-9 * scale)
        assert abs(w_hat[2]) < 1e-12 and abs(u1[2]) < 1e-12
    return used


def test_folded_matrix_equals_the_equations_synthetic():
    check_against_reference(S.load(), np.random.RandomState(1))


def test_folded_matrix_with_the_disturbance_low_pass():
    check_against_reference(S.load(), np.random.RandomState(7), a=0.03)


def test_folded_matrix_equals_the_equations_on_the_committed_gains():
    for name in ('physical', 'paper'):
        g = load_gains(gains_path(name))
        for a in (1.0, 0.05):
            used = check_against_reference(g, np.random.RandomState(2), a)
            # the disturbance enters the rates only, so y_k+1's positions drop out of the product
            assert used == [5, 6, 8, 9], name


def test_only_exactly_zero_columns_are_dropped():
    g = load_gains(PHYSICAL_GAINS)
    M, used = fold(g)
    full = fold_full(g)
    dropped = [j for j in range(10) if j not in used]
    assert np.all(full[:, N_FIXED + np.array(dropped)] == 0.0)
    assert M.shape == (18, N_FIXED + len(used))


def simulate(g, steps, w, x0, xt0, a=1.0):
    """Plant x+ = A x + B (u + w) measured exactly (y = x), in closed loop through the folded
    detector and control law, unsaturated. -> (x, x~, w-) histories."""
    A, B = S.plant()
    M, used = fold(g, a)
    x, xt = np.array(x0, float), np.array(xt0, float)
    y_prev = x.copy()
    u = np.zeros(5)
    w_bar = np.zeros(5)
    xs, xts, ws = [], [], []
    for _ in range(steps):
        x = A.dot(x) + B.dot(u + w)
        z = M.dot(np.concatenate([xt, w_bar[ACT], u[ACT], y_prev, x[used]]))
        xt = z[:10]
        u = np.zeros(5)
        u[ACT] = z[14:18]
        w_bar = np.zeros(5)
        w_bar[ACT] = z[10:14]
        y_prev = x.copy()
        xs.append(x)
        xts.append(xt)
        ws.append(w_bar)
    return np.array(xs), np.array(xts), np.array(ws)


W = np.array([0.8, -0.5, 0.0, 0.3, -0.2])
X0 = [0.01, -0.01, 0.05, 0.02, -0.03, 0, 0, 0.1, 0, 0]
XT0 = [0.0, 0.0, 0.0, 0.0, 0.0, 0.1, -0.1, 0.0, 0.2, 0.0]


def test_detector_converges_under_a_constant_input_disturbance():
    xs, xts, ws = simulate(S.load(), 12000, W, X0, XT0)   # 60 s: the slowest closed-loop mode is ~8 s
    err = np.abs(xts - xs).max(axis=1)
    assert err[0] > 1e-3                       # it starts wrong...
    assert err[30:].max() < 1e-9               # ...and the estimate error vanishes (poles 0.2)
    # w^_k estimates the disturbance of the step before: it converges to w
    np.testing.assert_allclose(ws[30:], np.tile(W, (len(ws) - 30, 1)), atol=1e-9)
    # and with K_w cancelling it, the LQR brings the robot back to rest
    assert np.abs(xs[-1]).max() < 1e-4


def test_low_passed_estimate_converges_too():
    a = 1 - np.exp(-2 * np.pi * 1.0 * S.TS)           # the default 1 Hz
    xs, xts, ws = simulate(S.load(), 12000, W, X0, XT0, a)
    assert np.abs(xts[30:] - xs[30:]).max() < 1e-9     # the state estimate is not filtered
    assert np.abs(ws[200] - W).max() > 1e-3            # the disturbance estimate lags...
    np.testing.assert_allclose(ws[2000:], np.tile(W, (len(ws) - 2000, 1)), atol=1e-9)   # ...then holds w
    assert np.abs(xs[-1]).max() < 1e-4


def test_a_plain_observer_would_not_converge(monkeypatch):
    # the same test with L2 = 0 (an ordinary Luenberger observer, Abar = A, L1 = A - 0.2 I):
    # the estimate error settles at a nonzero offset, which is what Section 6 removes (a gains
    # file would be refused for it: L2 is not E G_w, tipbot_fw.gains.STRUCTURE_CHECKS)
    monkeypatch.setattr('tipbot_fw.gains.STRUCTURE_CHECKS', [])
    doc = S.gains_doc()
    A = np.array(doc['A'])
    doc['L2'] = np.zeros((10, 10)).tolist()
    doc['L1'] = (A - 0.2 * np.eye(10)).tolist()
    xs, xts, _ = simulate(S.load(doc), 400, W, np.zeros(10), np.zeros(10))
    assert np.abs(xts[-50:] - xs[-50:]).max() > 1e-4
