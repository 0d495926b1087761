"""Gain design: LQR, finite horizon with disturbance, robust detector, errors, exported files."""
import json
import os
import re
import shutil
import subprocess
import sys

import numpy as np
import pytest

import dataclasses

from hostsim.model import design, kalman
from hostsim.model.equations import state_scale_to_si
from hostsim.errors import DesignError, ParameterError
from hostsim.model.gains import (DEFAULT_OUT_DIR, INTEGRAL_TIME_S, compare_documents, compare_with_file, design_gains,
                                 law_design,
                                 main as gains_main, output_name, to_document)
from hostsim.model.paper_check import TOLERANCE, cross_spectral_radii, run as paper_check_run
from hostsim.model.params import DEFAULT_PARAMS_PATH, load_params
from conftest import PARAMS_FILE, REPO

VARIANTS = ("paper", "physical")


@pytest.fixture(scope="module")
def designs(params):
    return {v: design_gains(v, params) for v in VARIANTS}


@pytest.fixture(scope="module")
def designs_10ms(params):
    return {v: design_gains(v, params, ts_s=0.010) for v in VARIANTS}


@pytest.mark.slow
def test_paper_check_within_tolerance():
    res = paper_check_run()
    for key, (median, worst, count) in res["errors"].items():
        assert count > 20, key
        assert worst <= TOLERANCE, "%s: max relative error %.3f %%" % (key, worst * 100)
        assert median < 0.001, key


def test_both_gains_stabilize_both_models(designs):
    radii = cross_spectral_radii(designs)
    assert set(radii) == {(g, m) for g in VARIANTS for m in VARIANTS}
    for pair, radius in radii.items():
        assert radius < 1.0, "%s gains on %s model: spectral radius %.5f" % (pair + (radius,))


@pytest.mark.parametrize("variant", VARIANTS)
def test_detector_condition_and_eigenvalues(designs, variant):
    g = designs[variant]
    n = 10
    residual = (g.L2 @ g.C - np.eye(n)) @ g.E
    assert np.abs(residual).max() < 1e-12
    abar = (np.eye(n) - g.L2 @ g.C) @ g.A
    eig = np.linalg.eigvals(abar - g.L1 @ g.C)
    assert np.allclose(np.sort(eig.real), design.DEFAULT_DETECTOR_POLE, atol=1e-9)
    assert np.abs(eig.imag).max() < 1e-9
    # L2 = E G_w: the detector's L2 term is the disturbance estimate pushed through E.
    assert np.allclose(g.L2, g.E @ g.G_w, atol=1e-12)


def test_detector_converges_under_constant_disturbance(designs):
    """Linear simulation of Section 6: the estimate and w^ converge despite w."""
    g = designs["paper"]
    a, b, c, e = g.A, g.B, g.C, g.E
    rng = np.random.default_rng(1)
    x = rng.normal(scale=[1, 1, 0.05, 0.05, 0.05, 1, 1, 0.1, 0.1, 0.1])
    xh = np.zeros(10)
    w = np.array([1.0, -0.5, 0.0, 0.3, 0.2])
    u = np.zeros(5)
    y = c @ x
    for _ in range(40):
        x_next = a @ x + b @ u + e @ w
        y_next = c @ x_next
        nu = y_next - c @ a @ xh - c @ b @ u
        w_hat = g.G_w @ nu
        xh = a @ xh + b @ u + g.L1 @ (y - c @ xh) + g.L2 @ nu
        x, y = x_next, y_next
        u = -g.K @ xh
    assert np.abs(xh - x).max() < 1e-9
    assert np.allclose(w_hat, w, atol=1e-9)


def test_finite_horizon_converges_to_steady_state_gain(designs):
    """Section 5.2's 800-step recursion reaches the DARE gain (paper README)."""
    g = designs["paper"]
    k_seq, ff, _ = design.finite_horizon_lqr(g.A, g.B, g.Q, g.R, g.Q, horizon=800)
    # The slowest closed-loop mode (|eig| 0.9937) leaves about 1e-4 after 800 steps.
    assert np.allclose(k_seq[0], g.K, rtol=2e-3, atol=1e-4 * np.abs(g.K).max())
    assert not np.allclose(k_seq[-1], g.K, rtol=0.1)  # the end of the horizon differs
    assert np.all(ff == 0)


def test_steady_state_feedforward_is_k_w(designs):
    """With a constant known w, the recursion's feedforward far from the end is -K_w w (the
    physical design's on its model with the integrators of the wheel positions)."""
    g = designs["physical"]
    w = np.array([1.0, 1.0, 0.0, 0.0, 0.0])
    horizon = 20000
    a, b = design.integrator_model(g.A, g.B, g.ts_s)
    e = design.integrator_model(g.A, g.E, g.ts_s)[1]
    q = np.zeros(a.shape)
    q[:10, :10] = g.Q
    q[10:, 10:] = np.eye(2) * g.Q[0, 0] / INTEGRAL_TIME_S ** 2
    assert g.P.shape == (12, 12)
    k_seq, ff, _ = design.finite_horizon_lqr(a, b, q, g.R, g.P, w_seq=np.tile(w, (horizon, 1)), e_mat=e)
    assert np.allclose(k_seq[0][:, :10], g.K, rtol=1e-6, atol=1e-9)
    assert np.allclose(ff[0], -g.K_w @ w, rtol=1e-6, atol=1e-9)
    assert np.abs(ff[0]).max() > 0.1  # the disturbance is not negligible


def test_k_w_reduces_the_cost_of_a_constant_disturbance(designs):
    g = designs["physical"]
    a, b, q, r = g.A, g.B, g.Q, g.R
    w = np.array([1.0, 1.0, 0.0, 0.0, 0.0])

    def cost(kw):
        x = np.zeros(10)
        total = 0.0
        for _ in range(4000):
            u = -g.K @ x - kw @ w
            total += x @ q @ x + u @ r @ u
            x = a @ x + b @ u + g.E @ w
        return total

    assert cost(g.K_w) < 0.9 * cost(np.zeros((5, 5)))


def test_other_sampling_period_goes_to_its_own_file_and_holds_both_models(designs_10ms, tmp_path):
    g = designs_10ms["physical"]
    doc = to_document(g)
    assert doc["ts_s"] == 0.01
    assert np.max(np.abs(g.closed_loop_eigenvalues)) < 1
    # At 10 ms the state feedback of the physical design loses the paper's model at any wheel
    # weight; with the Kalman filter in the loop, x100 holds the whole uncertainty set.
    assert doc["robust_to_models"]["stabilized"] is True and doc["r_wheel_scale"] == 100
    assert doc["robust_to_models"]["worst_spectral_radius"] <= kalman.ROBUST_RADIUS_MAX
    assert doc["robust_to_models"]["least_damping"] >= kalman.ROBUST_DAMPING_MIN
    assert doc["state_feedback_spectral_radius"]["paper"] > 1
    assert gains_main(["--variant", "paper", "--ts", "0.010", "--out-dir", str(tmp_path)]) == 0
    assert sorted(os.listdir(str(tmp_path))) == ["paper-ts0.010.json"]


@pytest.mark.parametrize("variant", VARIANTS)
def test_the_kalman_loop_holds_every_plant_of_the_uncertainty_set(designs, variant, params):
    g = designs[variant]
    kd = g.kalman
    physical = variant == "physical"
    # the physical design estimates joint 2's disturbance too, and has the wheels' integrators
    assert kd.n_filter == 13 + physical and kd.observability_rank == kd.n_filter
    assert kd.n == kd.n_filter + 2 * physical
    assert np.max(np.abs(kd.filter_eigenvalues)) < 1
    m = kalman.UncertaintySet(params, g.ts_s, payload=physical).margins(kd)
    assert m.robust and m == g.margins
    assert m.damping >= kalman.ROBUST_DAMPING_MIN
    # the loop's slowest mode is the filter's own (the gyro bias): nothing of the plant's is slower
    assert m.radius == pytest.approx(np.max(np.abs(kd.filter_eigenvalues)), abs=2e-4)


def margins_with(g, params, **noise):
    t = state_scale_to_si(g.variant)
    ti = np.linalg.inv(t)
    ns = dataclasses.replace(g.kalman.noise, **noise)
    kd = kalman.design_kalman(t @ g.A @ ti, t @ g.B, g.K @ ti, g.K_w, params["rw_m"], g.ts_s, ns, g.kalman.integral)
    return kalman.UncertaintySet(params, g.ts_s, payload=not g.variant.paper_conventions).margins(kd)


def test_joint_2s_disturbance_is_estimated_for_the_filter_not_compensated(designs):
    """The physical filter estimates w_th2 (links 2 and 3's load, the friction's mean) and the
    law leaves it alone (no integrator closed around the joint's friction and backlash): on the
    design's own model, at the loop's rest under 1 V held on joint 2's motor, the estimate takes
    the volt, to 5 %, and the tilt estimate stays within 1 mrad of the tilt; a filter without it
    (the same law) puts the tilt estimate several times further off, explaining the joint's
    load with a wrong lean."""
    g = designs["physical"]
    kd = g.kalman
    assert kd.state_names[10:13] == ("w_r", "w_l", "w_th2")
    assert np.all(kd.K[:, 12] == 0.0) and np.all(g.K_w[:, 3:] == 0.0)
    t = state_scale_to_si(g.variant)
    ti = np.linalg.inv(t)
    a, b = t @ g.A @ ti, t @ g.B
    wheels_only = kalman.design_kalman(a, b, g.K @ ti, g.K_w, kd.rw_m, g.ts_s,
                                       dataclasses.replace(kd.noise, disturbance_inputs=kalman.DISTURBANCE_INPUTS),
                                       kd.integral)

    def rest(design, joint_input):
        """The loop's rest (plant state, estimate) under 1 V more on a joint's motor."""
        big = kalman.loop_matrix(design, a, b, np.zeros_like(b))
        drive = np.zeros(big.shape[0])
        drive[:10] = b[:, joint_input]               # 1 V more on the joint's motor, forever
        x = np.linalg.solve(np.eye(big.shape[0]) - big, drive)
        return x[:10], x[10 + 4:]                    # the plant's state, the estimate
    x, xh = rest(kd, 3)
    assert xh[12] == pytest.approx(1.0, abs=0.05)
    err = abs(xh[2] - x[2])
    assert err < 1e-3
    x, xh = rest(wheels_only, 3)
    assert abs(xh[2] - x[2]) > 3 * err


def test_why_the_joints_are_weighted(designs, params):
    """The paper's Q weighs th2, th3 1 beside 1e7 on th1: with it the physical law does not hold
    0.15 kg at the top of link 3 (joint 3's servo softer than gravity's pull on the load); the
    ladder's joint weight does, with a stiffer joint 3."""
    g = designs["physical"]
    assert g.joint_weight_scale > 1
    q = g.Q.copy()
    q[3, 3] = q[4, 4] = 1.0
    k, p, eig, k_w, k_z = law_design(g.A, g.B, q, g.R, g.E, g.ts_s, True)
    t = state_scale_to_si(g.variant)
    ti = np.linalg.inv(t)
    kd = kalman.design_kalman(t @ g.A @ ti, t @ g.B, k @ ti, k_w, params["rw_m"], g.ts_s, g.kalman.noise,
                              kalman.integral_law(k_z / t[0, 0], params["u_max_v"]))
    soft = kalman.UncertaintySet(params, g.ts_s, payload=True).margins(kd)
    assert not soft.robust and soft.radius_at[3] == kalman.PAYLOAD_LABEL
    assert (g.K @ ti)[4, 4] > 1.3 * (k @ ti)[4, 4]     # joint 3's own stiffness, V/rad


def test_why_the_noise_settings_are_what_they_are(designs, params):
    g = designs["physical"]
    # a fast disturbance estimate (1 V^2/s) loses the paper model with the input delay
    m = margins_with(g, params, disturbance_rate_v2_per_s=1.0)
    assert m.radius > 1.0 and m.radius_at[0] == "paper" and m.radius_at[1] > 0
    # trusting the wheels' modelled acceleration leaves a wheel 20 % small too little damped
    m = margins_with(g, params, wheel_accel_noise_m_s2=0.0)
    assert m.damping < kalman.ROBUST_DAMPING_MIN and m.damping_at[3] == 0.8


def test_singular_r_is_refused(designs):
    g = designs["paper"]
    r = g.R.copy()
    r[3, 3] = 0.0
    with pytest.raises(DesignError, match="R is singular"):
        design.dlqr(g.A, g.B, g.Q, r, (0, 1, 3, 4))


def test_dead_input_column_is_refused(designs):
    g = designs["paper"]
    b = g.B.copy()
    b[:, 4] = 0.0
    with pytest.raises(DesignError, match="input column 4 of B is zero"):
        design.dlqr(g.A, b, g.Q, g.R, (0, 1, 3, 4))


def test_unsolvable_detector_condition_is_refused(designs):
    g = designs["paper"]
    e = g.E.copy()
    e[:, 3] = e[:, 4]  # two disturbances that act identically cannot be told apart
    with pytest.raises(DesignError, match="not solvable"):
        design.robust_detector(g.A, g.B, g.C, e, (0, 1, 3, 4))


def test_uncontrollable_system_is_refused(designs):
    g = designs["paper"]
    a = g.A.copy()
    b = g.B.copy()
    a[9, :] = 0.0
    a[:, 9] = 0.0
    a[9, 9] = 1.2
    b[9, :] = 0.0  # th3' now unreachable and unstable
    b[4, :] = 0.0
    with pytest.raises(DesignError, match="not controllable"):
        design.dlqr(a, b, g.Q, g.R, (0, 1, 3, 4))


def test_committed_gains_files_agree_with_a_regeneration(designs):
    for variant in VARIANTS:
        path = os.path.join(DEFAULT_OUT_DIR, variant + ".json")
        differences, agreement = compare_with_file(path, to_document(designs[variant]))
        assert not differences, "%s is stale: %s (run make gains)" % (path, "; ".join(differences))
        assert set(agreement) >= {"A", "B", "K", "K_w", "L1", "L2", "G_w"}


def test_the_comparison_tolerates_rounding_noise_but_not_a_change():
    with open(os.path.join(DEFAULT_OUT_DIR, "paper.json")) as f:
        committed = json.load(f)

    def changed(**fields):
        doc = json.loads(json.dumps(committed))
        doc.update(fields)
        return compare_documents(committed, doc)[0]

    k = np.array(committed["K"])
    assert changed(K=(k * (1 + 1e-9)).tolist()) == []              # what another BLAS kernel does
    assert changed(A=(np.array(committed["A"]) * (1 + 1e-13)).tolist()) == []
    k_bad = k.copy()
    k_bad[0, 2] *= 1.0001
    assert [d.split(":")[0] for d in changed(K=k_bad.tolist())] == ["K", "K"]   # its norm and its effect
    assert changed(A=(np.array(committed["A"]) * (1 + 1e-6)).tolist())[0].startswith("A: differs by 1e-06")
    assert changed(generator=committed["generator"] + " ")[0].startswith("generator: ")   # provenance: exact
    assert changed(parameters=dict(committed["parameters"], l1_m=0.1000000001))[0].startswith("parameters.l1_m")
    robust = {"models": ["physical"], "stabilized": False, "worst_spectral_radius": 1.01}
    assert changed(robust_to_models=robust) and all(d.startswith("robust_to_models") for d in changed(robust_to_models=robust))
    assert changed(K=k[:, :9].tolist())[0] == "K: shape changed"
    # the Kalman block: its gain and folded law by their conditioning, its provenance exactly
    kal = committed["kalman"]

    def kalman_with(**fields):
        return dict(kal, **fields)
    l_gain, law = np.array(kal["L"]), np.array(kal["law"]["M"])
    assert changed(kalman=kalman_with(L=(l_gain * (1 + 1e-12)).tolist(),
                                      law=dict(kal["law"], M=(law * (1 + 1e-9)).tolist()))) == []
    assert changed(kalman=kalman_with(L=(l_gain * (1 + 1e-7)).tolist()))[0].startswith("kalman.L: differs by 1e-07")
    assert changed(kalman=kalman_with(law=dict(kal["law"], M=(law * (1 + 1e-5)).tolist())))[0].startswith(
        "kalman.law.M: differs by 1e-05")
    noise = dict(kal["noise"], gyro_noise_dps=dict(kal["noise"]["gyro_noise_dps"], value=1.5))
    assert changed(kalman=kalman_with(noise=noise))[0].startswith("kalman.noise.gyro_noise_dps.value: 1.0 -> 1.5")


# (OPENBLAS_CORETYPE, the CPU flag its kernels need) per machine: the kernels the BLAS of
# another CPU would pick, forced on this one.
BLAS_KERNELS = {"x86_64": (("Prescott", "pni"), ("Haswell", "avx2"), ("Zen", "avx2"), ("SkylakeX", "avx512f")),
                "aarch64": (("ARMV8", "asimd"), ("CORTEXA57", "asimd"), ("NEOVERSEN1", "asimddp"))}
# Runs the gains command, first saying which OpenBLAS kernel numpy's BLAS runs.
WITH_KERNEL_NAME = r"""
import ctypes, glob, os, sys
import numpy
def corename():
    for lib in glob.glob(os.path.join(os.path.dirname(numpy.__file__) + ".libs", "*openblas*")):
        dll = ctypes.CDLL(lib)
        for sym in ("scipy_openblas_get_corename64_", "openblas_get_corename64_", "openblas_get_corename"):
            f = getattr(dll, sym, None)
            if f is not None:
                f.restype = ctypes.c_char_p
                return f().decode()
    return "unknown"
print("blas kernel: " + corename(), flush=True)
from hostsim.model.gains import main
sys.exit(main(sys.argv[1:]))
"""


def cpu_flags():
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith(("flags", "Features")):
                    return set(line.split(":", 1)[1].split())
    except OSError:
        pass
    return set()


@pytest.mark.slow
def test_make_gains_leaves_the_committed_files_untouched_under_other_blas_kernels(tmp_path, designs):
    """The BLAS of another CPU (forced with OPENBLAS_CORETYPE, which must be set before numpy
    loads: one process per kernel) regenerates numbers that agree within the tolerances, so
    the gains command leaves the files byte for byte as committed. (``designs``: the symbolic
    model's cache is built once, here, not in every process.)"""
    import platform
    flags = cpu_flags()
    kernels = [k for k, flag in BLAS_KERNELS.get(platform.machine(), ()) if flag in flags]
    assert kernels, "no OpenBLAS kernel listed for %s" % platform.machine()
    procs = {}
    for kernel in kernels:
        out_dir = tmp_path / kernel
        shutil.copytree(DEFAULT_OUT_DIR, str(out_dir))
        env = dict(os.environ, OPENBLAS_CORETYPE=kernel, OPENBLAS_VERBOSE="2")
        procs[kernel] = subprocess.Popen([sys.executable, "-c", WITH_KERNEL_NAME, "--out-dir", str(out_dir)],
                                         cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                         universal_newlines=True)
    cores = set()
    for kernel, proc in procs.items():
        out, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, out + err
        assert "Core not found" not in err and "core not found" not in err.lower(), (kernel, err)
        cores.add(out.split("\n", 1)[0])
        for variant in VARIANTS:
            assert "%s.json is up to date" % variant in out, out
            with open(os.path.join(DEFAULT_OUT_DIR, variant + ".json"), "rb") as a, \
                    open(str(tmp_path / kernel / (variant + ".json")), "rb") as b:
                assert a.read() == b.read(), (kernel, variant)
    assert len(cores) >= min(2, len(kernels)), cores     # the kernels really differed


@pytest.mark.slow
def test_make_gains_with_another_period_writes_its_own_file(tmp_path, designs):
    gains_dir = tmp_path / "gains"
    shutil.copytree(DEFAULT_OUT_DIR, str(gains_dir))
    os.unlink(str(gains_dir / "physical-ts0.010.json"))
    p = subprocess.run(["make", "--no-print-directory", "-C", REPO, "gains", "TS=0.010", "VARIANT=physical",
                        "GAINS_DIR=%s" % gains_dir], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                       universal_newlines=True, timeout=300)
    assert p.returncode == 0, p.stdout
    for variant in VARIANTS:
        with open(os.path.join(DEFAULT_OUT_DIR, variant + ".json"), "rb") as a, \
                open(str(gains_dir / (variant + ".json")), "rb") as b:
            assert a.read() == b.read(), variant
    assert "wrote %s (new file)" % (gains_dir / "physical-ts0.010.json") in p.stdout, p.stdout
    doc = json.load(open(str(gains_dir / "physical-ts0.010.json")))
    assert doc["ts_s"] == 0.01 and doc["robust_to_models"]["stabilized"] is True
    assert sorted(os.listdir(str(gains_dir))) == ["paper-ts0.010.json", "paper.json", "physical-ts0.010.json",
                                                  "physical.json"]
    # what it wrote is the committed fallback (docs/realistic-brick.md: when the brick cannot keep 5 ms)
    assert compare_with_file(os.path.join(DEFAULT_OUT_DIR, "physical-ts0.010.json"), doc)[0] == []


def test_gains_file_names_say_what_differs():
    assert output_name("physical") == "physical.json"
    assert output_name("physical", 0.005, DEFAULT_PARAMS_PATH) == "physical.json"
    assert output_name("paper", 0.010) == "paper-ts0.010.json"
    assert output_name("physical", 0.0075) == "physical-ts0.0075.json"
    assert output_name("physical", 0.005, "/tmp/my robot.json") == "physical-my_robot.json"
    assert output_name("physical", 0.02, "identified.json") == "physical-ts0.020-identified.json"


def test_committed_10ms_gains_files_agree_with_a_regeneration(designs_10ms):
    # the fallback for a brick that cannot keep 5 ms (docs/realistic-brick.md): make gains TS=0.010
    for variant in VARIANTS:
        path = os.path.join(DEFAULT_OUT_DIR, output_name(variant, 0.010))
        differences, _ = compare_with_file(path, to_document(designs_10ms[variant]))
        assert not differences, "%s is stale: %s (run make gains TS=0.010)" % (path, "; ".join(differences))


def test_gains_file_carries_its_provenance(designs):
    doc = json.load(open(os.path.join(DEFAULT_OUT_DIR, "physical.json")))
    for key in ("schema_version", "model_variant", "ts_s", "parameters", "parameters_sha256", "generator",
                "state_units", "K_w", "G_w", "detector_eigenvalues", "u_max_v"):
        assert key in doc
    assert doc["model_variant"] == "physical" and doc["state_units"][0] == "m"
    assert json.load(open(os.path.join(DEFAULT_OUT_DIR, "paper.json")))["state_units"][0] == "cm"


def write_params(tmp_path, mutate):
    doc = json.load(open(PARAMS_FILE))
    mutate(doc["parameters"])
    path = tmp_path / "robot.json"
    path.write_text(json.dumps(doc))
    return str(path)


@pytest.mark.parametrize("mutate, message", [
    (lambda p: p.pop("m2_kg"), "field parameters.m2_kg is missing"),
    (lambda p: p["l1_m"].update(value="ten"), "field parameters.l1_m must be a number in [0.001, 0.5], got 'ten'"),
    (lambda p: p["m1_kg"].update(value=-0.663), "field parameters.m1_kg must be a number in [0.001, 5.0], got -0.663"),
    (lambda p: p["rw_m"].update(value=0), "field parameters.rw_m must be a number in [0.005, 0.1], got 0"),
    (lambda p: p["joint2_beta_nm_s"].update(value=-1e-4),
     "field parameters.joint2_beta_nm_s must be a number in [0.0, 0.1], got -0.0001"),
    (lambda p: p.update(colour={"value": 1}), "field parameters.colour is unknown"),
])
@pytest.mark.slow
def test_bad_parameter_files_are_named(tmp_path, mutate, message):
    path = write_params(tmp_path, mutate)
    with pytest.raises(ParameterError, match="^" + re.escape(path + ": " + message) + "$"):
        load_params(path)
    # The command line ends with one line naming the cause, exit status 2.
    proc = subprocess.run([sys.executable, "-m", "hostsim", "gains", "--params", path, "--out-dir", str(tmp_path)],
                          capture_output=True, text=True, cwd=REPO)
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0 and message in proc.stderr


def test_unreadable_parameter_file_is_named(tmp_path):
    path = tmp_path / "nope.json"
    assert gains_main(["--params", str(path), "--out-dir", str(tmp_path)]) == 2
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ParameterError, match="bad.json: not valid JSON"):
        load_params(str(bad))
