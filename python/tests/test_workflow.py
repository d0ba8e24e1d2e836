"""The rest of the workflow in Python against the command line on the same model: the
reference integrators, stepped sines, nonlinear modes, test data from arrays, the virtual
test, planning and modal calibration. Where the same library path runs, the numbers must be
the command's to the last bit; bad input must raise an nlsim.Error naming the argument.

The command line is taken from $NLSIM_BIN (make test sets it to the debug build)."""

from __future__ import annotations

import _thread
import math
import threading
from pathlib import Path

import h5py
import numpy as np
import pytest

import nlsim

from test_nlsim import cli

ROOT = Path(__file__).resolve().parents[2]


# --- reference integrators, stepped sines, nonlinear modes ------------------------------


@pytest.mark.parametrize(
    "name,method,extra",
    [
        ("ecl_beam", "rk45", {}),
        ("bumpstop_cantilever", "rk45", {"rtol": 1e-5}),
        ("ecl_beam", "rk4", {"substeps": 4}),
        ("bumpstop_cantilever", "newmark", {"substeps": 2}),
        ("ecl_beam", "hht", {"hht_alpha": -0.1}),
    ],
)
def test_reference_integrators_equal_the_command_line(
    tmp_path: Path, name: str, method: str, extra: dict
) -> None:
    flags = []
    for k, v in extra.items():
        flags += ["--" + k.replace("_", "-"), repr(v)]
    cli("simulate", name, "--method", method, "--duration", "0.1", "--rate", "4000",
        *flags, "--out", "h.h5", cwd=tmp_path)
    got = nlsim.simulate(nlsim.load(name), 0.1, 4000.0, method=method, **extra)
    assert got.status == "converged", got.detail
    with h5py.File(tmp_path / "h.h5") as h:
        np.testing.assert_array_equal(got.time, h["time"][:])
        for j, s in enumerate(got.sensors):
            np.testing.assert_array_equal(got.outputs[:, j], h[f"outputs/{s}"][:])
    # The unreduced integrators keep no modes; the reduced ones the default 20 or fewer.
    assert (got.modes == 0) == (method in ("newmark", "hht"))


def test_foh_converges_to_rk45_at_second_order() -> None:
    """Independent integrators on the linear ECL beam (k3 = 0), started from rest under the
    default sine: FOH's error against a tight RK45 falls as dt^2 (measured 1.3e-4 of the
    peak at 4 kHz, 1.1e-5 at 16 kHz: a ratio of 12 where pure second order gives 16; the
    rest is the two runs' common floor near 8e-6)."""
    m = nlsim.load("ecl_beam")
    m.set("tip_spring.k3", 0.0)
    ref = nlsim.simulate(m, 0.3, 4000.0, method="rk45", rtol=1e-9, atol=1e-14)
    scale = np.abs(ref.outputs).max()
    err = []
    for k in (1, 4):
        foh = nlsim.simulate(m, 0.3, 4000.0 * k)
        err.append(np.abs(foh.outputs[::k] - ref.outputs).max() / scale)
    assert err[0] <= 2e-4 and err[1] <= err[0] / 8, err


@pytest.mark.parametrize("mode,points", [("step-up", 60), ("step-down", None)])
def test_stepped_sines_equal_the_command_line(tmp_path: Path, mode: str, points) -> None:
    flags = [] if points is None else ["--points", str(points)]
    lo, hi = ("20", "40") if mode == "step-up" else ("40", "20")
    cli("frf", "ecl_beam", "--from", lo, "--to", hi, "--mode", mode, *flags,
        "--out", "f.h5", cwd=tmp_path)
    got = nlsim.frf(nlsim.load("ecl_beam"), float(lo), float(hi), mode=mode, points=points)
    # The command line's default is 400 frequencies.
    assert len(got) == (points or 400)
    with h5py.File(tmp_path / "f.h5") as h:
        np.testing.assert_array_equal(got.frequency_hz, h["frequency"][:])
        np.testing.assert_array_equal(got.stable, h["stable"][:])
        for j, s in enumerate(got.sensors):
            np.testing.assert_array_equal(got.response[:, j, :], h[f"sensors/{s}/response"][:])
    # Through the hardening resonance the response jumps: down past the upper fold when
    # stepping up, up past the lower fold when stepping down.
    tip = np.abs(got.response[:, 0, 1])
    assert np.abs(np.diff(tip)).max() > 0.3 * tip.max()


def test_nonlinear_mode_equals_the_command_line(tmp_path: Path) -> None:
    cli("nnm", "ecl_beam", "--from", "1e-5", "--to", "1e-3", "--points", "12",
        "--out", "n.h5", cwd=tmp_path)
    got = nlsim.nnm(nlsim.load("ecl_beam"), 1e-5, 1e-3, points=12)
    assert got.status == "converged" and len(got) == 12
    with h5py.File(tmp_path / "n.h5") as h:
        for key in ("amplitude", "damping_ratio", "xi"):
            np.testing.assert_array_equal(getattr(got, key), h[key][:])
        np.testing.assert_array_equal(got.frequency_hz, h["frequency"][:])
        for j, s in enumerate(got.sensors):
            np.testing.assert_array_equal(got.response[:, j, :], h[f"sensors/{s}/response"][:])
    # At the smallest amplitude the backbone starts at the linear mode (cubic: the shift
    # grows as amplitude squared, 1e-3 relative here).
    f1 = nlsim.modes(nlsim.load("ecl_beam"), count=1).frequency_hz[0]
    assert abs(got.frequency_hz[0] - f1) < 1e-3 * f1
    assert np.all(np.diff(got.frequency_hz) > 0)  # hardening
    assert list(got.to_dataframe().columns[:3]) == ["amplitude", "frequency_hz", "damping_ratio"]


# --- test data, the virtual test, calibration on arrays --------------------------------

TEST_FILE = {
    "harmonics": 3,
    "seed": 11,
    "noise": {"relative": 0.02},
    "shaker": {"armature_mass": 0.05},
    "sweep": [
        {"label": "0.1 N up", "from": 21.0, "to": 27.0, "steps": 13, "force": 0.1},
        {"label": "0.05 N down", "from": 27.0, "to": 21.0, "steps": 9, "force": 0.05},
    ],
}

TEST_TOML = """harmonics = 3
seed = 11
noise = { relative = 0.02 }

[shaker]
armature_mass = 0.05

[[sweep]]
label = "0.1 N up"
from = 21.0
to = 27.0
steps = 13
force = 0.1

[[sweep]]
label = "0.05 N down"
from = 27.0
to = 21.0
steps = 9
force = 0.05
"""


def test_virtual_test_equals_the_command_line_and_calibrates_from_arrays(tmp_path: Path) -> None:
    """`nlsim test` and `nlsim.virtual_test` on the same file give the same bytes of test
    data; the data rebuilt from their arrays calibrate to the bit as the file does, and a
    TestData saved by the package is read by the command line to the same estimates."""
    (tmp_path / "t.toml").write_text(TEST_TOML)
    cli("test", "ecl_beam", "t.toml", "--out", "d.csv", cwd=tmp_path)
    model = nlsim.load("ecl_beam")
    for spec in (TEST_FILE, TEST_TOML, tmp_path / "t.toml"):
        vt = nlsim.virtual_test(model, spec)
        vt.data.save(tmp_path / "py.csv")
        assert (tmp_path / "py.csv").read_bytes() == (tmp_path / "d.csv").read_bytes()
    assert vt.drive == "shaker" and vt.open_loop is not None
    assert vt.force.shape == (22, 4) and vt.voltage.shape == (22, 4)
    np.testing.assert_array_equal(vt.frequency_hz[:13], np.linspace(21.0, 27.0, 13))
    # The controller holds the force within its 1 % default.
    assert vt.force_error.max() <= 0.01

    loaded = nlsim.TestData.load(tmp_path / "d.csv", model)
    assert loaded.channels == ["tip", "mid"] and loaded.harmonics == 3 and len(loaded) == 22
    sweeps = loaded.sweeps
    assert [s["label"] for s in sweeps] == ["0.1 N up", "0.05 N down"]
    assert [s["direction"] for s in sweeps] == ["up", "down"]
    assert sweeps[0]["response"].shape == (13, 2, 3) and sweeps[0]["force"].shape == (13, 3)
    rebuilt = nlsim.TestData(
        loaded.input,
        dict(zip(loaded.channels, loaded.quantities)),
        [{k: s[k] for k in ("label", "frequency_hz", "force", "response", "sigma", "direction")}
         for s in sweeps],
        noise=[n[1] for n in loaded.noise],
        noise_absolute=[n[0] for n in loaded.noise],
    )
    # nlsim test's noise: 2 % with a floor of 1e-3 of each channel's largest response.
    assert [n[1] for n in loaded.noise] == [0.02, 0.02] and min(n[0] for n in loaded.noise) > 0
    rebuilt.save(tmp_path / "rebuilt.csv")
    params = {"tip_spring.k3": (1e9, 2e10), "mode2.zeta": (0.001, 0.05)}
    a = nlsim.calibrate(model, tmp_path / "d.csv", params, lhs=12, folds=0)
    b = nlsim.calibrate(model, rebuilt, params, lhs=12, folds=0)
    np.testing.assert_array_equal(a.estimate, b.estimate)
    np.testing.assert_array_equal(a.cramer_rao_std, b.cramer_rao_std)
    cli("calibrate", "ecl_beam", "rebuilt.csv", "--param", "tip_spring.k3=1e9:2e10",
        "--param", "mode2.zeta=0.001:0.05", "--lhs", "12", "--folds", "0",
        "--out", "est.csv", cwd=tmp_path)
    rows = [l.split(",") for l in (tmp_path / "est.csv").read_text().splitlines()[1:]]
    assert [float(r[1]) for r in rows] == list(b.estimate)
    # The truth the test was made with: k3 = 6e9 N/m^3, zeta2 = 0.01.
    assert abs(b.estimate[0] - 6e9) < 3 * b.cramer_rao_std[0]
    assert abs(b.estimate[1] - 0.01) < 3 * b.cramer_rao_std[1]
    df = loaded.to_dataframe()
    assert len(df) == 22 and list(df.columns[:4]) == ["sweep", "step", "frequency_hz", "force"]


def test_raw_records_equal_the_command_line(tmp_path: Path) -> None:
    """A test file with `[raw]`: `VirtualTest.raw` holds the samples `nlsim test` writes to
    its raw CSV (to the file's nine digits), the step table's windows, and the noise each
    channel got; without `[raw]` it is None."""
    test = dict(TEST_FILE, noise={"relative": 0.01}, force_noise={"relative": 0.01},
                raw={"out": "raw.csv", "rate": 2000.0, "dwell": 3.0})
    test["sweep"] = [{"label": "up", "from": 22.0, "to": 24.0, "steps": 3, "force": 0.1}]
    toml = tmp_path / "t.toml"
    vt = nlsim.virtual_test(nlsim.load("ecl_beam"), test)
    raw = vt.raw
    assert raw is not None and raw["rate_hz"] == 2000.0 and raw["status"] == "converged"
    assert raw["dwell_s"] == 3.0 and raw["oversample"] >= 1
    lines = [
        "harmonics = 3", "seed = 11", "noise = { relative = 0.01 }",
        "force_noise = { relative = 0.01 }", "[shaker]", "armature_mass = 0.05",
        "[raw]", 'out = "raw.csv"', "rate = 2000.0", "dwell = 3.0", "[[sweep]]",
        'label = "up"', "from = 22.0", "to = 24.0", "steps = 3", "force = 0.1",
    ]
    toml.write_text("\n".join(lines) + "\n")
    cli("test", "ecl_beam", "t.toml", "--out", "d.csv", cwd=tmp_path)
    rows = [l for l in (tmp_path / "raw.csv").read_text().splitlines() if not l.startswith("#")]
    head = rows[0].split(",")
    vals = np.array([[float(x) for x in r.split(",")] for r in rows[1:]])
    assert len(vals) == len(raw["time_s"]) == 3 * 6000
    np.testing.assert_allclose(vals[:, 0], raw["time_s"], rtol=0, atol=1e-12)
    cols = {
        "tip_acceleration_m_per_s2": raw["responses"]["tip"],
        "mid_acceleration_m_per_s2": raw["responses"]["mid"],
        "shaker_force_N": raw["force"],
        "shaker_voltage_V": raw["voltage"],
    }
    assert head[1:] == list(cols)
    for j, name in enumerate(head[1:], start=1):
        x = cols[name]
        np.testing.assert_allclose(vals[:, j], x, rtol=1e-8, atol=1e-9 * np.abs(x).max())
    table = [l.split(",") for l in (tmp_path / "raw_steps.csv").read_text().splitlines()[1:]]
    assert len(table) == len(raw["steps"]) == 3
    for row, step in zip(table, raw["steps"]):
        assert abs(float(row[0]) * 2000.0 - step["measured"]) < 1e-6
        assert abs(float(row[1]) * 2000.0 - (step["end"] - 1)) < 1e-6
        assert row[3] == step["sweep"] == "up"
    # 1 % of each channel's rms: the noise the samples carry.
    tip = raw["responses"]["tip"]
    assert abs(raw["noise_std"]["tip"] - 0.01 * np.sqrt(np.mean(tip**2))) < 1e-4 * raw["noise_std"]["tip"]
    assert nlsim.virtual_test(nlsim.load("ecl_beam"), TEST_FILE).raw is None


def test_voltage_records_calibrate_through_a_shaker_as_the_command_line(tmp_path: Path) -> None:
    """An open-loop test recorded as voltage over an amplifier gain of 8: `calibrate` with
    `shaker` and the input gain among the parameters gives the calibration file's estimates
    (`[shaker]`) to the bit, and a fixed gain (`gains`) starts a calibrated one there; bad
    gains and shakers are refused by name."""
    test = {
        "harmonics": 3, "modes": 4, "seed": 2, "record": "voltage", "amplifier_gain": 8.0,
        "control": {"enabled": False},
        "sweep": [{"label": "high", "from": 21.5, "to": 26.5, "steps": 21, "force": 0.2}],
    }
    model = nlsim.load("ecl_beam")
    data = nlsim.virtual_test(model, test).data
    data.save(tmp_path / "volt.csv")
    (tmp_path / "cal.toml").write_text(
        'model = "ecl_beam"\ndata = "volt.csv"\nharmonics = 3\nmodes = 4\nlhs = 12\n'
        'starts = 2\nfolds = 0\nout = "est.csv"\n\n[shaker]\nresistance = 1.5\n\n'
        '[[param]]\nname = "tip_spring.k3"\nlower = 6e8\nupper = 6e10\n\n'
        '[[param]]\nname = "input_gain"\nlower = 1.0\nupper = 50.0\n'
    )
    cli("calibrate", "--config", "cal.toml", cwd=tmp_path)
    rows = [l.split(",") for l in (tmp_path / "est.csv").read_text().splitlines()[1:]]
    params = {"tip_spring.k3": (6e8, 6e10), "input_gain": (1.0, 50.0)}
    c = nlsim.calibrate(model, data, params, modes=4, lhs=12, starts=2, folds=0,
                        shaker={"resistance": 1.5})
    assert [float(r[1]) for r in rows] == list(c.estimate)
    assert abs(c.estimate[1] - 8.0) < 3 * c.cramer_rao_std[1]
    # nlsim's default shaker has resistance 1.5 too: the same bits.
    d = nlsim.calibrate(model, data, params, modes=4, lhs=12, starts=2, folds=0, shaker=True)
    np.testing.assert_array_equal(c.estimate, d.estimate)
    # Without the shaker the voltage is taken as the force: far off.
    far = nlsim.calibrate(model, data, {"tip_spring.k3": (6e8, 6e10)}, modes=4, lhs=12,
                          starts=2, folds=0, gains={"input_gain": 8.0})
    assert far.reduced_chi2 > 10 * c.reduced_chi2
    with pytest.raises(nlsim.InputError, match="'speed' is no field"):
        nlsim.calibrate(model, data, params, shaker={"speed": 1.0})
    with pytest.raises(nlsim.InputError, match="'tip_spring.k3' is no gain"):
        nlsim.calibrate(model, data, params, gains={"tip_spring.k3": 1.0})


def test_test_data_from_arrays_is_checked_by_name() -> None:
    """Closed form: a linear one-channel sweep whose per-step standard deviations are given
    calibrates against that noise; and every malformed array is refused naming it."""
    f = np.linspace(20.0, 28.0, 5)
    ok = {"frequency_hz": f, "force": np.full(5, 0.1), "response": np.ones((5, 1)) * 1e-4j}
    d = nlsim.TestData("shaker", {"tip": "acceleration"}, [ok])
    assert d.harmonics == 1 and d.sweeps[0]["direction"] == "up" and d.sweeps[0]["sigma"] is None
    down = dict(ok, frequency_hz=f[::-1], sigma=np.full((5, 1), 1e-6 + 2e-6j))
    d2 = nlsim.TestData("shaker", {"tip": "acceleration"}, [down])
    assert d2.sweeps[0]["direction"] == "down"
    np.testing.assert_array_equal(d2.sweeps[0]["sigma"][:, 0, 0], np.full(5, 1e-6 + 2e-6j))
    cases = [
        (dict(ok, response=np.ones((4, 1))), r"sweeps\[0\]\['response'\]: shape \(4, 1\)"),
        (dict(ok, force=np.ones((5, 2))), r"sweeps\[0\]\['force'\]: 2 harmonic\(s\), but the response holds 1"),
        (dict(ok, sigma=np.ones((5, 2))), r"sweeps\[0\]\['sigma'\]: shape \(5, 2\), not the response's"),
        (dict(ok, frequency_hz=np.ones((5, 1))), r"sweeps\[0\]\['frequency_hz'\]: shape"),
        (dict(ok, frequency_hz=["a"] * 5), r"sweeps\[0\]\['frequency_hz'\]: not convertible"),
        (dict(ok, direction="sideways"), r"sweeps\[0\]\['direction'\]: expected 'up' or 'down'"),
        (dict(ok, speed=1.0), r"sweeps\[0\]: unknown key 'speed'"),
        ({"force": np.ones(5)}, r"sweeps\[0\]: no 'frequency_hz'"),
        (dict(ok, force=np.array([0.1, 0.1, np.nan, 0.1, 0.1])), "test data: "),
    ]
    for sweep, message in cases:
        with pytest.raises(nlsim.InputError, match=message):
            nlsim.TestData("shaker", {"tip": "acceleration"}, [sweep])
    with pytest.raises(nlsim.InputError, match=r"channels\['tip'\]: .*jerk"):
        nlsim.TestData("shaker", {"tip": "jerk"}, [ok])
    with pytest.raises(nlsim.InputError, match="drive: 'current'"):
        nlsim.TestData("shaker", {"tip": "acceleration"}, [ok], drive="current")
    with pytest.raises(nlsim.InputError, match="sweeps: give at least one sweep"):
        nlsim.TestData("shaker", {"tip": "acceleration"}, [])
    with pytest.raises(nlsim.InputError, match="writes test data as .csv"):
        d.save("d.h5")


def test_plan_equals_the_command_line(tmp_path: Path) -> None:
    plan = {
        "params": ["tip_spring.k3", "mode2.zeta"],
        "levels": [0.05, 0.2],
        "measured": [[1], [1, 3]],
        "band": [{"label": "across", "from": 21.0, "to": 27.0, "steps": 9}],
    }
    text = "\n".join([
        'params = ["tip_spring.k3", "mode2.zeta"]',
        "levels = [0.05, 0.2]",
        "measured = [[1], [1, 3]]",
        "[[band]]",
        'label = "across"',
        "from = 21.0",
        "to = 27.0",
        "steps = 9",
    ]) + "\n"
    (tmp_path / "p.toml").write_text(text)
    cli("plan", "ecl_beam", "p.toml", "--report", "rep", cwd=tmp_path)
    got = nlsim.plan(nlsim.load("ecl_beam"), plan)
    lines = (tmp_path / "rep" / "ranking.csv").read_text().splitlines()
    head = lines[0].split(",")
    rows = [l.split(",") for l in lines[1:]]
    assert len(got) == len(rows) > 1
    col = {h: i for i, h in enumerate(head)}
    np.testing.assert_array_equal(got.log_det, [float(r[col["log_det"]]) for r in rows])
    np.testing.assert_array_equal(got.max_variance, [float(r[col["max_variance"]]) for r in rows])
    for j, p in enumerate(got.params):
        np.testing.assert_array_equal(got.relative_std[:, j], [float(r[col[f"std_{p}"]]) for r in rows])
    assert [d[5] for d in got.designs] == [r[col["harmonics"]] for r in rows]
    # The D criterion ranks by ln det F, largest first.
    assert np.all(np.diff(got.log_det) <= 0)
    assert got.to_dataframe().index[0] == 1
    with pytest.raises(nlsim.FileError, match=r"<plan>:\d+: speed: unknown field `speed`"):
        nlsim.plan(nlsim.load("ecl_beam"), dict(plan, speed=2))


MODES_CSV = """mode,frequency_hz,frequency_std_hz,2:ux,4:ux,6:ux
1,5.706751,0.0057,0.2108,0.5273,0.7091
2,14.000702,0.014,-0.5522,-0.1795,0.6047
5,32.048107,0.032,,,
"""


def test_modal_calibration_equals_the_command_line(tmp_path: Path) -> None:
    """docs/calibration.md's measured modes of the grouped chain: the package and the
    command line give the same estimates and bounds; the same modes given as arrays (the
    fifth mode's frequency alone is left out: arrays give a shape to every mode or none)
    refuse what is malformed by name."""
    (tmp_path / "modes.csv").write_text(MODES_CSV)
    model_file = str(ROOT / "examples" / "models" / "grouped_chain6.toml")
    cli("calibrate", model_file, "modes.csv", "--param", "group:root.k_scale=0.5:2",
        "--param", "group:tip.m_scale=0.5:1.5", "--param", "spring:6:ux.k=100:5000",
        "--out", "est.csv", "--report", "rep", cwd=tmp_path)
    model = nlsim.load(model_file)
    params = {"group:root.k_scale": (0.5, 2.0), "group:tip.m_scale": (0.5, 1.5),
              "spring:6:ux.k": (100.0, 5000.0)}
    got = nlsim.calibrate_modal(model, tmp_path / "modes.csv", params)
    rows = [l.split(",") for l in (tmp_path / "est.csv").read_text().splitlines()[1:]]
    assert got.params == [r[0] for r in rows]
    for j, r in enumerate(rows):
        assert got.estimate[j] == float(r[1])
        assert got.cramer_rao_std[j] == float(r[2])
        assert got.chi2_scaled_std[j] == float(r[4])
    fit = [l.split(",") for l in (tmp_path / "rep" / "modes.csv").read_text().splitlines()[1:]]
    assert got.pairing == [int(r[4]) - 1 for r in fit]
    np.testing.assert_array_equal(got.frequency_hz, [float(r[3]) for r in fit])
    np.testing.assert_array_equal(got.mac[:2], [float(r[5]) for r in fit[:2]])
    assert math.isnan(got.mac[2])  # the fifth mode's shape was not measured
    assert got.fe_stats["fe_reduction"] == "parametric" and got.fe_stats["basis_size"] > 0
    # A full eigen solve per evaluation: the command line's --fe-reduction full to the bit,
    # and the parametric estimates within 1e-3 of the Cramér–Rao bound of it.
    cli("calibrate", model_file, "modes.csv", "--param", "group:root.k_scale=0.5:2",
        "--param", "group:tip.m_scale=0.5:1.5", "--param", "spring:6:ux.k=100:5000",
        "--fe-reduction", "full", "--out", "full.csv", cwd=tmp_path)
    full = nlsim.calibrate_modal(model, tmp_path / "modes.csv", params, fe_reduction="full")
    rows = [l.split(",") for l in (tmp_path / "full.csv").read_text().splitlines()[1:]]
    np.testing.assert_array_equal(full.estimate, [float(r[1]) for r in rows])
    assert full.fe_stats["fe_reduction"] == "full"
    assert full.fe_stats["full_reductions"] == full.fe_stats["evaluations"] > 0
    assert np.all(np.abs(got.estimate - full.estimate) <= 1e-3 * full.cramer_rao_std)
    with pytest.raises(nlsim.InputError, match="fe_reduction: 'exact'"):
        nlsim.calibrate_modal(model, tmp_path / "modes.csv", params, fe_reduction="exact")
    with pytest.raises(nlsim.InputError, match="fe_tolerance: a tolerance belongs"):
        nlsim.calibrate_modal(model, tmp_path / "modes.csv", params, fe_reduction="full",
                              fe_tolerance=1e-8)
    arrays = {
        "frequency_hz": np.array([5.706751, 14.000702]),
        "frequency_std_hz": np.array([0.0057, 0.014]),
        "dofs": ["2:ux", "4:ux", "6:ux"],
        "shapes": np.array([[0.2108, -0.5522], [0.5273, -0.1795], [0.7091, 0.6047]]),
    }
    two = {"group:root.k_scale": (0.5, 2.0), "group:tip.m_scale": (0.5, 1.5)}
    from_arrays = nlsim.calibrate_modal(model, arrays, two)
    assert from_arrays.status == "converged"
    with pytest.raises(nlsim.InputError, match=r"data\['dofs'\]\[1\]: '99:ux'"):
        nlsim.calibrate_modal(model, dict(arrays, dofs=["2:ux", "99:ux", "6:ux"]), two)
    with pytest.raises(nlsim.InputError, match=r"data\['shapes'\]: shape \(2, 3\)"):
        nlsim.calibrate_modal(model, dict(arrays, shapes=arrays["shapes"].T), two)
    with pytest.raises(nlsim.InputError, match="data: mode 2: frequency must be positive"):
        nlsim.calibrate_modal(model, dict(arrays, frequency_hz=np.array([5.7, -1.0])), two)
    with pytest.raises(nlsim.InputError, match="give 'dofs' and 'shapes' together"):
        nlsim.calibrate_modal(model, {k: arrays[k] for k in ("frequency_hz", "frequency_std_hz", "dofs")}, two)


def test_bad_workflow_arguments_raise_input_errors_naming_them() -> None:
    ecl = nlsim.load("ecl_beam")
    with pytest.raises(nlsim.InputError, match="mode 'step-down' goes down, but from_hz 20"):
        nlsim.frf(ecl, 20, 30, mode="step-down")
    with pytest.raises(nlsim.InputError, match=r"noise: 2 values for 1 channel\(s\)"):
        nlsim.TestData("shaker", {"tip": "acceleration"}, [], noise=[0.1, 0.2])
    with pytest.raises(nlsim.InputError, match="mode: 'sweep'"):
        nlsim.frf(ecl, 20, 30, mode="sweep")
    with pytest.raises(nlsim.InputError, match="points: 1"):
        nlsim.frf(ecl, 20, 30, mode="step-up", points=1)
    with pytest.raises(nlsim.InputError, match="points: a stepped sine's frequency count"):
        nlsim.frf(ecl, 20, 30, points=10)
    with pytest.raises(nlsim.InputError, match="hht_alpha: -0.5"):
        nlsim.simulate(ecl, 0.1, 1000, method="hht", hht_alpha=-0.5)
    with pytest.raises(nlsim.InputError, match="rtol: 0"):
        nlsim.simulate(ecl, 0.1, 1000, method="rk45", rtol=0.0)
    with pytest.raises(nlsim.InputError, match="substeps: 0"):
        nlsim.simulate(ecl, 0.1, 1000, method="rk4", substeps=0)
    with pytest.raises(nlsim.InputError, match="from_amplitude: -1"):
        nlsim.nnm(ecl, -1.0, 1e-3)
    with pytest.raises(nlsim.InputError, match="mode: 3 needs|modes: 2; mode 3"):
        nlsim.nnm(ecl, 1e-5, 1e-3, mode=3, modes=2)
    with pytest.raises(nlsim.InputError, match="no nonlinear element"):
        nlsim.nnm(nlsim.from_matrices(np.eye(2), np.diag([1.0, 4.0])), 1e-5, 1e-3)
    with pytest.raises(nlsim.FileError, match=r"<test>:.*speed"):
        nlsim.virtual_test(ecl, dict(TEST_FILE, speed=3))
    with pytest.raises(nlsim.FileError, match="nothing.toml"):
        nlsim.virtual_test(ecl, "nothing.toml")
    with pytest.raises(nlsim.InputError, match="data: expected an nlsim.TestData or the path"):
        nlsim.calibrate(ecl, 3.0, {"tip_spring.k3": (1e9, 2e10)})


def test_balance_points_equal_the_stepped_sine() -> None:
    """A sweep of one's own with Balance.solve (from rest, then each from the last) is the
    stepped sine frf(mode="step-up") runs, to the bit, on a range without a jump."""
    model = nlsim.load("ecl_beam")
    freqs = np.linspace(20.0, 24.0, 21)
    ref = nlsim.frf(model, 20.0, 24.0, mode="step-up", points=21)
    bal = nlsim.Balance(model)
    p = bal.solve(float(freqs[0]))
    rows = [p.response]
    for f in freqs[1:]:
        p = bal.solve(float(f), start=p.x)
        assert p.status == "converged" and p.seconds > 0
        rows.append(p.response)
    np.testing.assert_array_equal(np.array(rows), ref.response)
    assert bal.n_unknowns == p.x.shape[0]
    with pytest.raises(nlsim.InputError, match="start: 3 values; the balance has"):
        bal.solve(22.0, start=np.zeros(3))
    with pytest.raises(nlsim.InputError, match="freq_hz: -1"):
        bal.solve(-1.0)


def test_bump_stop_calibration_equals_the_command_line(tmp_path: Path) -> None:
    """The bump-stop cantilever: `nlsim test` then `nlsim calibrate` of the stop's stiffness
    and gap, and the same through virtual_test and calibrate in Python: the same estimates
    and statistics to the bit, within 3 Cramer-Rao std of the model's k1 and e1."""
    test = {
        "harmonics": 9, "seed": 3, "noise": {"relative": 0.01},
        "sweep": [{"label": "up", "from": 20.0, "to": 30.0, "steps": 15, "force": 0.5}],
    }
    (tmp_path / "t.toml").write_text(
        'harmonics = 9\nseed = 3\nnoise = { relative = 0.01 }\n\n[[sweep]]\nlabel = "up"\n'
        "from = 20.0\nto = 30.0\nsteps = 15\nforce = 0.5\n"
    )
    cli("test", "bumpstop_cantilever", "t.toml", "--out", "d.csv", cwd=tmp_path)
    cli("calibrate", "bumpstop_cantilever", "d.csv", "--param", "stop.k1=2e4:2e6",
        "--param", "stop.e1=5e-4:2e-3", "--harmonics", "9", "--lhs", "8", "--folds", "3",
        "--out", "est.csv", cwd=tmp_path)
    model = nlsim.load("bumpstop_cantilever")
    truth = [model.get("stop.k1"), model.get("stop.e1")]
    data = nlsim.virtual_test(model, test).data
    c = nlsim.calibrate(model, data, {"stop.k1": (2e4, 2e6), "stop.e1": (5e-4, 2e-3)},
                        harmonics=9, lhs=8, folds=3)
    rows = [l.split(",") for l in (tmp_path / "est.csv").read_text().splitlines()[1:]]
    for j, r in enumerate(rows):
        assert c.estimate[j] == float(r[1])
        assert c.cramer_rao_std[j] == float(r[2])
        assert c.kfold_mean[j] == float(r[3])
        assert c.kfold_std[j] == float(r[4])
        assert abs(c.estimate[j] - truth[j]) < 3 * c.cramer_rao_std[j]


def test_time_domain_calibration_equals_the_command_line(tmp_path: Path) -> None:
    """A sweep through the bump-stop cantilever recorded by `nlsim simulate` (CSV), calibrated
    by the package from the CSV's columns as numpy arrays and by `nlsim calibrate
    --time-domain` from the file: the same estimates and bounds to the bit (the same doubles,
    the same noise of 1 % of each channel's rms), near the model's 2e5 N/m and 1 mm."""
    cli("simulate", "bumpstop_cantilever", "--excitation", "sweep:f0=19,f1=28.4,amp=0.6",
        "--rate", "3786", "--duration", "3", "--out", "sweep.csv", cwd=tmp_path)
    bounds = ["--param", "stop.k1=5e4:1e6", "--param", "stop.e1=5e-4:2e-3"]
    cli("calibrate", "bumpstop_cantilever", "sweep.csv", "--time-domain", *bounds,
        "--set", "stop.k1=4e5", "--set", "stop.e1=1.5e-3", "--lhs", "16", "--folds", "3",
        "--out", "est.csv", cwd=tmp_path)
    table = np.loadtxt(tmp_path / "sweep.csv", delimiter=",", comments="#", skiprows=2)
    head = [l for l in (tmp_path / "sweep.csv").read_text().splitlines() if not l.startswith("#")][0]
    col = {name: i for i, name in enumerate(head.split(","))}
    model = nlsim.load("bumpstop_cantilever")
    model.set("stop.k1", 4e5)
    model.set("stop.e1", 1.5e-3)
    got = nlsim.calibrate_time(
        model,
        table[:, col["shaker_force_N"]],
        {"tip": table[:, col["tip_acceleration_m_per_s2"]],
         "mid": table[:, col["mid_acceleration_m_per_s2"]]},
        3786.0,
        {"stop.k1": (5e4, 1e6), "stop.e1": (5e-4, 2e-3)},
        lhs=16,
        folds=3,
    )
    rows = [l.split(",") for l in (tmp_path / "est.csv").read_text().splitlines()[1:]]
    assert got.params == [r[0] for r in rows]
    for j, r in enumerate(rows):
        assert got.estimate[j] == float(r[1])
        assert got.cramer_rao_std[j] == float(r[2])
        assert got.kfold[0][j] == float(r[3])
    assert abs(got.estimate[0] / 2e5 - 1) < 0.02 and abs(got.estimate[1] / 1e-3 - 1) < 0.005
    assert set(got.simulated) == {"tip", "mid"} and got.simulated["tip"].shape == (table.shape[0],)
    # Ctrl-C keeps the candidates evaluated so far; resume= goes on to the estimates of an
    # uninterrupted call, bit for bit.
    force = table[:, col["shaker_force_N"]]
    responses = {"tip": table[:, col["tip_acceleration_m_per_s2"]]}
    bounds_py = {"stop.k1": (5e4, 1e6), "stop.e1": (5e-4, 2e-3)}
    args = dict(lhs=300, folds=2, threads=1)
    whole = nlsim.calibrate_time(model, force, responses, 3786.0, bounds_py, **args)
    timer = threading.Timer(0.2, _thread.interrupt_main)
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt) as caught:
            nlsim.calibrate_time(model, force, responses, 3786.0, bounds_py, **args)
    finally:
        timer.cancel()
    partial = caught.value.args[1]
    assert isinstance(partial, nlsim.PartialCalibration) and partial.candidates.shape == (301, 2)
    resumed = nlsim.calibrate_time(model, force, responses, 3786.0, bounds_py, resume=partial, **args)
    np.testing.assert_array_equal(resumed.estimate, whole.estimate)
    np.testing.assert_array_equal(resumed.cramer_rao_std, whole.cramer_rao_std)
    with pytest.raises(nlsim.InputError, match="responses\\['tip'\\]: zero"):
        nlsim.calibrate_time(model, table[:, 3], {"tip": np.zeros(table.shape[0])}, 3786.0,
                             {"stop.k1": (5e4, 1e6)})
    with pytest.raises(nlsim.InputError, match="channel 'mid': samples"):
        nlsim.calibrate_time(model, table[:, 3], {"mid": table[:10, 2]}, 3786.0,
                             {"stop.k1": (5e4, 1e6)})
