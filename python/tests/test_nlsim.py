"""Tests of the Python package against independent references: the nlsim command line on the
same model (HDF5 results read by h5py; equal to the last bit, the same library code runs),
scipy's eigsh on exported matrices, and closed forms. Bad input must raise an nlsim.Error
subclass naming the argument.

The command line is taken from $NLSIM_BIN (make test sets it to the debug build)."""

from __future__ import annotations

import _thread
import math
import os
import subprocess
import threading
from pathlib import Path

import h5py
import numpy as np
import pytest
import scipy.io
import scipy.sparse as sp
import scipy.sparse.linalg as sla

import nlsim

NLSIM = os.environ.get("NLSIM_BIN", "nlsim")


def cli(*args: str, cwd: Path) -> None:
    """Runs the command line, failing the test with its stderr."""
    r = subprocess.run([NLSIM, "--quiet", *args], cwd=cwd, capture_output=True, text=True)
    assert r.returncode == 0, f"nlsim {' '.join(args)}: {r.stderr}"


def f64(x: float) -> str:
    """A float as text that parses back to the same double (the command line's argument)."""
    return repr(float(x))


# --- the same results as the command line ------------------------------------------------


@pytest.mark.parametrize("name", ["ecl_beam", "bumpstop_cantilever"])
def test_modes_equal_the_command_line(tmp_path: Path, name: str) -> None:
    cli("modes", name, "--out", "m.h5", cwd=tmp_path)
    got = nlsim.modes(nlsim.load(name))
    with h5py.File(tmp_path / "m.h5") as h:
        np.testing.assert_array_equal(got.frequency_hz, h["modes/frequency_hz"][:])
        np.testing.assert_array_equal(got.eigenvalues, h["modes/eigenvalue_rad2_s2"][:])
        np.testing.assert_array_equal(got.damping_ratio, h["modes/damping_ratio"][:])
        np.testing.assert_array_equal(got.shapes, h["modes/shapes"][:].T)
        for comp, masses in got.effective_mass.items():
            np.testing.assert_array_equal(masses, h[f"modes/effective_mass_{comp}_kg"][:])
        labels = [s.decode() if isinstance(s, bytes) else s for s in h["dofs/labels"][:]]
        assert got.dofs == labels


def frf_range(model: nlsim.Model) -> tuple[float, float]:
    f1 = float(nlsim.modes(model, count=1).frequency_hz[0])
    return round(0.8 * f1, 3), round(1.4 * f1, 3)


@pytest.mark.parametrize("name", ["ecl_beam", "bumpstop_cantilever"])
def test_frf_branch_with_stability_equals_the_command_line(tmp_path: Path, name: str) -> None:
    model = nlsim.load(name)
    lo, hi = frf_range(model)
    cli("frf", name, "--from", f64(lo), "--to", f64(hi), "--out", "f.h5", cwd=tmp_path)
    got = nlsim.frf(model, lo, hi)
    assert got.status == "converged", got.detail
    with h5py.File(tmp_path / "f.h5") as h:
        np.testing.assert_array_equal(got.frequency_hz, h["frequency"][:])
        np.testing.assert_array_equal(got.level, h["level"][:])
        np.testing.assert_array_equal(got.stable, h["stable"][:])
        np.testing.assert_array_equal(got.harmonics, h["harmonic_ratio"][:])
        codes = {"regular": 0, "fold": 1, "end": 2, "jump": 3}
        np.testing.assert_array_equal([codes[k] for k in got.kind], h["kind"][:])
        for j, s in enumerate(got.sensors):
            np.testing.assert_array_equal(got.response[:, j, :], h[f"sensors/{s}/response"][:])
        assert len(got.bifurcations) == h["bifurcations/frequency"].shape[0]
        np.testing.assert_array_equal(
            [b[1] for b in got.bifurcations], h["bifurcations/frequency"][:]
        )


@pytest.mark.parametrize("name", ["ecl_beam", "bumpstop_cantilever"])
def test_foh_history_equals_the_command_line(tmp_path: Path, name: str) -> None:
    cli("simulate", name, "--duration", "0.2", "--rate", "4000", "--out", "h.h5", cwd=tmp_path)
    got = nlsim.simulate(nlsim.load(name), 0.2, 4000.0)
    assert got.status == "converged"
    with h5py.File(tmp_path / "h.h5") as h:
        np.testing.assert_array_equal(got.time, h["time"][:])
        for j, s in enumerate(got.sensors):
            np.testing.assert_array_equal(got.outputs[:, j], h[f"outputs/{s}"][:])
        for e, name_e in enumerate(got.elements):
            np.testing.assert_array_equal(
                got.element_forces[:, e], h[f"elements/{name_e}/force"][:]
            )


def test_excitation_specs_and_samples_drive_the_same_run() -> None:
    """A spec string and the same force given as samples give the same response: the FOH
    holds the spec's samples at the steps linearly, as it holds given samples, so the runs
    differ only by the last bit of numpy's sine against Rust's (relative 1e-12 allowed)."""
    model = nlsim.load("ecl_beam")
    rate, duration = 4000.0, 0.25
    t = np.arange(int(duration * rate) + 1) / rate
    force = 0.5 * np.sin(2 * math.pi * 5.0 * t)
    a = nlsim.simulate(model, duration, rate, excitation={"shaker": "sine:freq=5,amp=0.5"})
    b = nlsim.simulate(model, duration, rate, excitation={"shaker": force})
    scale = np.abs(a.outputs).max()
    assert np.abs(a.outputs - b.outputs).max() <= 1e-12 * scale
    np.testing.assert_allclose(b.forces[:, 0], force, rtol=0, atol=1e-15)
    assert b.excitation == ["1001 samples at 4000 Hz"]


def test_results_do_not_depend_on_the_thread_count() -> None:
    model = nlsim.load("ecl_beam")
    one = nlsim.frf(model, 20.0, 40.0, threads=1)
    two = nlsim.frf(model, 20.0, 40.0, threads=2)
    assert one.status == "converged" and len(one) > 100 and len(one.folds) == 2
    np.testing.assert_array_equal(one.frequency_hz, two.frequency_hz)
    np.testing.assert_array_equal(one.response, two.response)
    m1 = nlsim.modes(nlsim.load("bracket:dofs=3000"), count=6, threads=1)
    m2 = nlsim.modes(nlsim.load("bracket:dofs=3000"), count=6, threads=2)
    np.testing.assert_array_equal(m1.frequency_hz, m2.frequency_hz)
    np.testing.assert_array_equal(m1.shapes, m2.shapes)


TEST_FILE = """harmonics = 3
seed = 7
noise = { relative = 0.02 }

[[sweep]]
label = "0.1 N up"
from = 21.0
to = 27.0
steps = 13
force = 0.1
"""


def test_calibration_equals_the_command_line_and_finds_the_truth(tmp_path: Path) -> None:
    """A virtual test of the ECL beam (nlsim test: shaker, force control, 2 % noise, seeded),
    calibrated by the command line and by the package with the same settings: the same
    estimates, Cramer-Rao and k-fold statistics to the bit; k3 within 3 Cramer-Rao std of the
    6e9 N/m^3 the data were made with."""
    (tmp_path / "t.toml").write_text(TEST_FILE)
    cli("test", "ecl_beam", "t.toml", "--out", "d.csv", "--report", "rep", cwd=tmp_path)
    cli(
        "calibrate", "ecl_beam", "d.csv",
        "--param", "tip_spring.k3=1e9:2e10", "--param", "mode1.zeta=0.001:0.05",
        "--lhs", "16", "--folds", "4", "--out", "est.csv",
        cwd=tmp_path,
    )
    c = nlsim.calibrate(
        nlsim.load("ecl_beam"),
        tmp_path / "d.csv",
        {"tip_spring.k3": (1e9, 2e10), "mode1.zeta": (0.001, 0.05)},
        lhs=16,
        folds=4,
    )
    rows = [l.split(",") for l in (tmp_path / "est.csv").read_text().splitlines()[1:]]
    assert c.params == [r[0] for r in rows]
    for j, r in enumerate(rows):
        assert c.estimate[j] == float(r[1])
        assert c.cramer_rao_std[j] == float(r[2])
        assert c.kfold_mean[j] == float(r[3])
        assert c.kfold_std[j] == float(r[4])
        assert c.jackknife_std[j] == float(r[5])
        assert c.at_bound[j] == (r[6] == "true")
        assert c.poorly_identified[j] == (r[7] == "true")
        assert c.chi2_scaled_std[j] == float(r[8])
        assert c.chi2_scaled_std[j] == c.cramer_rao_std[j] * math.sqrt(c.reduced_chi2)
    assert c.status == "converged"
    assert abs(c.estimate[0] - 6e9) < 3 * c.cramer_rao_std[0]
    # 16 Latin-hypercube candidates and the model's own values.
    assert c.candidates.shape == (17, 2) and c.candidate_cost.shape == (17,)
    df = c.to_dataframe()
    assert list(df.index) == c.params
    with pytest.raises(nlsim.InputError, match="unknown parameter 'tip.k9'; known parameters: tip_spring.k3, mode1.f"):
        nlsim.calibrate(nlsim.load("ecl_beam"), tmp_path / "d.csv", {"tip.k9": (1, 2)})
    with pytest.raises(nlsim.InputError, match="bounds"):
        nlsim.calibrate(nlsim.load("ecl_beam"), tmp_path / "d.csv", {"tip_spring.k3": (2e10, 1e9)})
    # Sizes are bounded as the command line bounds them (5000 harmonics once panicked).
    with pytest.raises(nlsim.InputError, match="harmonics=5000: give 1 to 64"):
        nlsim.calibrate(nlsim.load("ecl_beam"), tmp_path / "d.csv", {"tip_spring.k3": (1e9, 2e10)}, harmonics=5000)
    with pytest.raises(nlsim.InputError, match="harmonics=5000: give 1 to 256"):
        nlsim.Balance(nlsim.load("ecl_beam"), harmonics=5000)
    with pytest.raises(nlsim.FileError, match="d.h5: HDF5: this build of nlsim reads and writes no HDF5"):
        nlsim.calibrate(nlsim.load("ecl_beam"), tmp_path / "d.h5", {"tip_spring.k3": (1e9, 2e10)})
    with pytest.raises(nlsim.FileError, match="nothing.csv"):
        nlsim.calibrate(nlsim.load("ecl_beam"), tmp_path / "nothing.csv", {"tip_spring.k3": (1e9, 2e10)})


# --- independent oracles -----------------------------------------------------------------


def test_eigenvalues_equal_scipy_eigsh_on_the_exported_bracket(tmp_path: Path) -> None:
    cli("export", "bracket", str(tmp_path / "b"), cwd=tmp_path)
    K = scipy.io.mmread(tmp_path / "b" / "K.mtx").tocsc()
    M = scipy.io.mmread(tmp_path / "b" / "M.mtx").tocsc()
    # Matrix Market keeps one triangle of a symmetric matrix; scipy restores both.
    dofs = (tmp_path / "b" / "dofs.txt").read_text().split()
    model = nlsim.from_matrices(M, K, dofs=dofs, name="bracket")
    assert model.n_dofs == K.shape[0] == len(dofs)
    got = nlsim.modes(model, count=10)
    lam, _ = sla.eigsh(K, k=10, M=M, sigma=0.0, which="LM", tol=1e-14)
    lam = np.sort(lam)
    rel = np.abs(got.eigenvalues[:10] - lam) / lam
    assert rel.max() < 1e-10, rel
    # The shapes are M-orthonormal and satisfy K phi = lambda M phi (residual < 1e-8).
    phi = got.shapes
    np.testing.assert_allclose(phi.T @ (M @ phi), np.eye(phi.shape[1]), atol=1e-9)


def test_two_dof_chain_has_its_closed_form_frequencies() -> None:
    k, m = 1.0e4, 2.0
    K = sp.csr_matrix(np.array([[2 * k, -k], [-k, 2 * k]]))
    M = sp.diags([m, m]).tocsr()
    model = nlsim.from_matrices(M, K, dofs=["1:ux", "2:ux"])
    expected = np.sqrt(np.array([k / m, 3 * k / m])) / (2 * math.pi)
    np.testing.assert_allclose(nlsim.modes(model).frequency_hz, expected, rtol=1e-13)


def test_weakly_forced_duffing_follows_the_linear_receptance() -> None:
    """The SDOF Duffing oscillator of thesis Fig. 3 forced at 1e-9 of its level is linear to
    ~1e-12 (the cubic force k3 x^3 against k x at x ~ 1e-16 m): its first harmonic is the
    receptance F / (k - m w^2 + i c w) (cosine convention: x = Re X e^{i w t})."""
    m, c, k, k3 = 450.0, 250.0, 1.5e7, 1.7e15
    M = sp.csr_matrix([[m]])
    K = sp.csr_matrix([[k]])
    model = nlsim.from_matrices(M, K, dofs=["1:u"], name="duffing")
    model.set_rayleigh(c / m, 0.0)
    model.add_element("spring", f"cubic k3={k3}", "1:u")
    model.add_excitation("force", "1:u", 2.0)
    model.add_sensor("x", "1:u")
    assert model.parameters == ["spring.k3"]
    assert model.get("spring.k3") == k3
    r = nlsim.frf(model, 25.0, 31.0, harmonics=3, level=1e-9, stability=False)
    w = 2 * math.pi * r.frequency_hz
    X = 2e-9 / (k - m * w**2 + 1j * c * w)
    got = r.response[:, 0, 1]
    assert np.abs(got - X).max() <= 1e-9 * np.abs(X).max()


def test_parameters_are_set_by_their_text_form() -> None:
    model = nlsim.load("ecl_beam")
    soft = model.copy()
    soft.set("tip_spring.k3", 0.0)
    assert model.get("tip_spring.k3") == 6e9
    assert soft.get("tip_spring.k3") == 0.0
    with pytest.raises(nlsim.InputError, match="tip_spring.k3"):
        model.get("tip_spring.k4")


def test_model_files_of_every_fe_format_load_and_hdf5_is_refused_plainly(tmp_path: Path) -> None:
    """The example model files (Matrix Market, DMIG, Abaqus, OUTPUT4, Harwell-Boeing) load
    into one model; an HDF5 matrix names the file and what to do instead (no libhdf5 here)."""
    models = Path(__file__).resolve().parents[2] / "examples" / "models"
    ref = nlsim.modes(nlsim.load(str(models / "spring_mass.toml")), count=3)
    for name in ["spring_mass_dmig", "spring_mass_abaqus", "spring_mass_op4", "spring_mass_hb"]:
        got = nlsim.modes(nlsim.load(str(models / f"{name}.toml")), count=3)
        np.testing.assert_allclose(got.frequency_hz, ref.frequency_hz, rtol=1e-12)
    text = (models / "spring_mass.toml").read_text()
    text = text.replace('stiffness = "spring_mass.mtx"', 'stiffness = "k.h5:K"')
    (tmp_path / "m.toml").write_text(text.replace('"spring_mass', f'"{models}/spring_mass'))
    with pytest.raises(nlsim.FileError, match=r"k\.h5: HDF5: this build of nlsim reads and writes no HDF5"):
        nlsim.load(str(tmp_path / "m.toml"))


# --- Python behaviour ----------------------------------------------------------------------


def test_ctrl_c_interrupts_a_long_run() -> None:
    """A run far longer than the test (FOH over 2e7 steps) stops at Ctrl-C with
    KeyboardInterrupt, the interpreter intact."""
    model = nlsim.load("ecl_beam")
    timer = threading.Timer(1.0, _thread.interrupt_main)
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            nlsim.simulate(model, 5000.0, 4000.0, threads=1)
    finally:
        timer.cancel()
    assert nlsim.modes(model, count=1).frequency_hz[0] > 0


def test_ctrl_c_keeps_a_calibration_and_resume_matches_bit_for_bit(tmp_path: Path) -> None:
    """Ctrl-C during a calibration raises KeyboardInterrupt carrying what was complete (a
    PartialCalibration: the candidates evaluated so far); calibrate(..., resume=it) goes on to
    the estimates of an uninterrupted call, bit for bit."""
    (tmp_path / "t.toml").write_text(TEST_FILE)
    cli("test", "ecl_beam", "t.toml", "--out", "d.csv", cwd=tmp_path)
    model = nlsim.load("ecl_beam")
    params = {"tip_spring.k3": (1e9, 2e10), "mode1.zeta": (0.001, 0.05)}
    args = dict(harmonics=7, modes=8, lhs=400, folds=4, threads=1)
    whole = nlsim.calibrate(model, tmp_path / "d.csv", params, **args)
    timer = threading.Timer(0.3, _thread.interrupt_main)
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt) as caught:
            nlsim.calibrate(model, tmp_path / "d.csv", params, **args)
    finally:
        timer.cancel()
    partial = caught.value.args[1]
    assert isinstance(partial, nlsim.PartialCalibration)
    assert partial.params == whole.params
    assert partial.candidates.shape == (401, 2)
    evaluated = ~np.isnan(partial.candidate_cost)
    assert partial.evaluated == evaluated.sum()
    assert partial.phase in ("candidates", "optimisation", "cross validation")
    # What it kept are the uninterrupted call's candidates and costs.
    np.testing.assert_array_equal(partial.candidates, whole.candidates)
    np.testing.assert_array_equal(partial.candidate_cost[evaluated], whole.candidate_cost[evaluated])
    resumed = nlsim.calibrate(model, tmp_path / "d.csv", params, resume=partial, **args)
    np.testing.assert_array_equal(resumed.estimate, whole.estimate)
    np.testing.assert_array_equal(resumed.cramer_rao_std, whole.cramer_rao_std)
    np.testing.assert_array_equal(resumed.kfold_mean, whole.kfold_mean)
    with pytest.raises(nlsim.InputError, match="resume: its candidates are not this calibration's"):
        nlsim.calibrate(model, tmp_path / "d.csv", params, resume=partial, **{**args, "seed": 2})


def test_reduced_model_is_reused_by_the_runs() -> None:
    model = nlsim.load("ecl_beam")
    red = nlsim.reduce(model, modes=20)
    # 20 asked; a degenerate pair at the cut is kept whole.
    assert red.n_modes >= 20 and red.residual_flexibility
    assert red.frequency_hz.shape == (red.n_modes,)
    a = nlsim.frf(red, 20.0, 40.0)
    b = nlsim.frf(model, 20.0, 40.0)
    assert len(a) > 100
    np.testing.assert_array_equal(a.response, b.response)


def test_results_become_dataframes() -> None:
    pd = pytest.importorskip("pandas")
    r = nlsim.frf(nlsim.load("ecl_beam"), 20.0, 40.0)
    df = r.to_dataframe()
    assert isinstance(df, pd.DataFrame) and len(df) == len(r) > 100
    np.testing.assert_array_equal(df["tip_h1"].to_numpy(), r.response[:, 0, 1])
    m = nlsim.modes(nlsim.load("ecl_beam")).to_dataframe()
    assert m.index[0] == 1 and "effective_mass_uz_kg" in m.columns
    h = nlsim.simulate(nlsim.load("ecl_beam"), 0.01, 4000.0).to_dataframe()
    assert list(h.columns) == ["time_s", "tip", "mid"] and len(h) == 41


# --- bad input: an exception naming the argument, never a crash ---------------------------


def spring_mass() -> tuple[sp.csr_matrix, sp.csr_matrix]:
    K = sp.csr_matrix(np.array([[2.0, -1.0], [-1.0, 2.0]]) * 1e4)
    M = sp.identity(2, format="csr")
    return M, K


def test_bad_matrices_raise_input_errors_naming_them() -> None:
    M, K = spring_mass()
    with pytest.raises(nlsim.InputError, match="K: shape 3 x 2 is not square"):
        nlsim.from_matrices(M, sp.csr_matrix(np.ones((3, 2))))
    with pytest.raises(nlsim.InputError, match="K: shape 3 x 3; the model has 2 DOFs"):
        nlsim.from_matrices(M, sp.identity(3))
    with pytest.raises(nlsim.InputError, match=r"stiffness matrix is not symmetric: entry \(1:u, 2:u\) = -1e0 but \(2:u, 1:u\) = -1.5e0"):
        nlsim.from_matrices(M, sp.csr_matrix(np.array([[2.0, -1.0], [-1.5, 2.0]])))
    bad = K.copy()
    bad.data[0] = np.nan
    with pytest.raises(nlsim.InputError, match=r"K: entry \(0, 0\) is NaN, not a finite number"):
        nlsim.from_matrices(M, bad)
    with pytest.raises(nlsim.InputError, match="not real"):
        nlsim.from_matrices(M, K.astype(np.complex128))
    with pytest.raises(nlsim.InputError, match="dofs: 3 labels for a model of 2 DOFs"):
        nlsim.from_matrices(M, K, dofs=["1:ux", "2:ux", "3:ux"])
    with pytest.raises(nlsim.InputError, match=r"dofs\[1\]"):
        nlsim.from_matrices(M, K, dofs=["1:ux", "two"])
    with pytest.raises(nlsim.InputError, match="mass"):
        nlsim.from_matrices(sp.csr_matrix((2, 2)), K)
    with pytest.raises(nlsim.InputError, match="M: indptr has 2 entries; a 2 x 2 matrix has 3"):
        nlsim.Model.from_csr("x", 2, np.array([0, 1]), np.array([0]), np.array([1.0]), K.indptr, K.indices, K.data)
    with pytest.raises(nlsim.InputError, match=r"M: indices\[0\] is 7, outside a 2 x 2 matrix"):
        nlsim.Model.from_csr("x", 2, np.array([0, 1, 2]), np.array([7, 1]), np.array([1.0, 1.0]), K.indptr, K.indices, K.data)


def test_bad_arguments_raise_input_errors_naming_them() -> None:
    for cls in (nlsim.InputError, nlsim.FileError, nlsim.ComputationError):
        assert issubclass(cls, nlsim.Error) and issubclass(cls, Exception)
    M, K = spring_mass()
    model = nlsim.from_matrices(M, K, dofs=["1:ux", "2:ux"])
    with pytest.raises(nlsim.InputError, match="dof"):
        model.add_sensor("s", "9:ux")
    with pytest.raises(nlsim.InputError, match="quantity"):
        model.add_sensor("s", "1:ux", "jerk")
    with pytest.raises(nlsim.InputError, match="law"):
        model.add_element("e", "cubic k3=abc", "1:ux")
    with pytest.raises(nlsim.InputError, match="unknown parameter 'e.k3'"):
        model.set("e.k3", 1.0)
    # A linear model has an FRF; one without an excitation has nothing to force.
    with pytest.raises(nlsim.InputError, match="no excitation point to force"):
        nlsim.frf(model, 10, 20)
    ecl = nlsim.load("ecl_beam")
    with pytest.raises(nlsim.InputError, match="from_hz and to_hz are both 20"):
        nlsim.frf(ecl, 20, 20)
    with pytest.raises(nlsim.ComputationError, match="no point converged, not even the start point at 25 Hz"):
        nlsim.frf(ecl, 25.0, 35.0)
    with pytest.raises(nlsim.InputError, match="threads: 0"):
        nlsim.frf(ecl, 20, 30, threads=0)
    with pytest.raises(nlsim.InputError, match="expected an nlsim.Model or nlsim.Reduced, got str"):
        nlsim.frf("ecl_beam", 20, 30)
    with pytest.raises(nlsim.InputError, match="no excitation point 'nope'"):
        nlsim.simulate(ecl, 0.1, 1000, excitation={"nope": "sine:freq=5"})
    with pytest.raises(nlsim.InputError, match=r"excitation\['shaker'\]: sample 3 is NaN"):
        nlsim.simulate(ecl, 0.1, 1000, excitation={"shaker": np.array([0, 1, 2, np.nan])})
    with pytest.raises(nlsim.InputError, match="Nyquist"):
        nlsim.simulate(ecl, 0.1, 1000, excitation={"shaker": "sine:freq=900"})
    with pytest.raises(nlsim.InputError, match="method: 'rk9'"):
        nlsim.simulate(ecl, 0.1, 1000, method="rk9")
    with pytest.raises(nlsim.InputError, match="neither a model file nor a built-in model"):
        nlsim.load("no_such_model")
    with pytest.raises(nlsim.FileError, match="missing.toml"):
        nlsim.load("missing.toml")
    with pytest.raises(TypeError):
        nlsim.modes(ecl, count="ten")  # type: ignore[arg-type]


# --- the guide ---------------------------------------------------------------------------


def test_the_worked_script_of_the_guide_runs_as_written(tmp_path: Path) -> None:
    """docs/python.md's script, exactly as the guide prints it, and what the guide says it
    prints."""
    pytest.importorskip("matplotlib")
    guide = (Path(__file__).resolve().parents[2] / "docs" / "python.md").read_text()
    section = guide.split("## A worked example", 1)[1]
    script = section.split("```python\n", 1)[1].split("```", 1)[0]
    import sys

    r = subprocess.run(
        [sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True
    )
    assert r.returncode == 0, r.stderr
    assert "natural frequencies (Hz): [ 23.948 150.082 420.239 823.539]" in r.stdout
    assert "folds at [32.98 25.94] Hz" in r.stdout
    assert "2 fold(s), converged" in r.stdout
    # The calibration finds the cubic stiffness and damping the beam was built with.
    import re

    est = re.search(r"tip_spring.k3 = (\S+) ± (\S+), mode1.zeta = (\S+) ± (\S+);", r.stdout)
    assert est, r.stdout
    k3, s_k3, zeta, s_zeta = (float(x) for x in est.groups())
    assert abs(k3 - 6e9) < 3 * s_k3 and abs(zeta - 0.01) < 3 * s_zeta
    png = tmp_path / "cantilever.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
