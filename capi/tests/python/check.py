"""A Python caller of libnlsim_c through ctypes (standard library only).

Builds the 2-DOF cubic chain of examples/two_dof_cubic.rs from CSR arrays, reduces it,
simulates it, solves a harmonic-balance point with sensitivities, follows the FRF, reads and
sets a parameter and makes deliberately bad calls. Prints `key value...` lines that
capi/tests/foreign.rs compares with the Rust API; exits non-zero on an unexpected code.

Usage: python3 check.py /path/to/libnlsim_c.so /path/to/examples
"""

import ctypes as C
import math
import sys

lib = C.CDLL(sys.argv[1])
examples = sys.argv[2]

OK, STOPPED_SHORT, ERR_NULL, ERR_SIZE, ERR_HANDLE, ERR_INPUT, ERR_NUMERICAL, ERR_IO = (
    0, 1, -1, -2, -3, -4, -5, -6)

handle = C.c_uint64
dbl_p = C.POINTER(C.c_double)
i64_p = C.POINTER(C.c_int64)


class Sparse(C.Structure):
    _fields_ = [("format", C.c_int32), ("triangle", C.c_int32), ("index_base", C.c_int32),
                ("ptr", i64_p), ("idx", i64_p), ("values", dbl_p)]


class ModelInfo(C.Structure):
    _fields_ = [(n, C.c_size_t) for n in
                ("n_dofs", "n_elements", "n_inputs", "n_sensors", "n_params")]


class RunInfo(C.Structure):
    _fields_ = [("status", C.c_int32), ("samples", C.c_size_t),
                ("newton_iterations", C.c_size_t)]


class HbInfo(C.Structure):
    _fields_ = [(n, C.c_size_t) for n in
                ("harmonics", "n_sensors", "n_inputs", "n_unknowns", "n_params")]


class PointInfo(C.Structure):
    _fields_ = [("status", C.c_int32), ("iterations", C.c_size_t), ("residual", C.c_double),
                ("stable", C.c_int32), ("max_floquet_real", C.c_double)]


class FrfInfo(C.Structure):
    _fields_ = [("status", C.c_int32)] + [(n, C.c_size_t) for n in
                                          ("n_points", "n_folds", "n_rejected", "n_newton")]


code = C.c_int32
signatures = {
    "nlsim_version": ([], C.c_char_p),
    "nlsim_last_error": ([], C.c_char_p),
    "nlsim_free": ([handle], code),
    "nlsim_live_handles": ([C.POINTER(C.c_size_t)], code),
    "nlsim_model_new": ([C.c_char_p, C.c_size_t, C.POINTER(C.c_char_p), C.POINTER(Sparse),
                         C.POINTER(Sparse), C.POINTER(handle)], code),
    "nlsim_model_set_rayleigh": ([handle, C.c_double, C.c_double], code),
    "nlsim_model_add_element": ([handle, C.c_char_p, C.c_char_p, C.c_char_p, C.c_char_p],
                                code),
    "nlsim_model_add_coupled_element": ([handle, C.c_char_p, C.c_char_p,
                                         C.POINTER(C.c_char_p), C.c_size_t], code),
    "nlsim_model_add_excitation": ([handle, C.c_char_p, C.c_char_p, C.c_double], code),
    "nlsim_model_add_sensor": ([handle, C.c_char_p, C.c_char_p, C.c_int32], code),
    "nlsim_model_info": ([handle, C.POINTER(ModelInfo)], code),
    "nlsim_model_load": ([C.c_char_p, C.POINTER(handle)], code),
    "nlsim_get_param": ([handle, C.c_char_p, dbl_p], code),
    "nlsim_set_param": ([handle, C.c_char_p, C.c_double], code),
    "nlsim_reduce": ([handle, C.c_size_t, C.c_int32, C.POINTER(handle)], code),
    "nlsim_reduced_frequencies": ([handle, dbl_p, C.c_size_t], code),
    "nlsim_simulate": ([handle, C.c_double, C.c_size_t, dbl_p, C.c_size_t, dbl_p, C.c_size_t,
                        C.POINTER(RunInfo)], code),
    "nlsim_hb_new": ([handle, C.c_size_t, C.POINTER(handle)], code),
    "nlsim_hb_info": ([handle, C.POINTER(HbInfo)], code),
    "nlsim_hb_point": ([handle, C.c_double, C.c_double, C.c_int32, dbl_p, C.c_size_t,
                        C.POINTER(PointInfo)], code),
    "nlsim_hb_sensitivities": ([handle, C.c_double, C.c_double, C.POINTER(C.c_char_p),
                                C.c_size_t, dbl_p, C.c_size_t, dbl_p, C.c_size_t,
                                C.POINTER(PointInfo)], code),
    "nlsim_frf": ([handle, C.c_double, C.c_double, C.c_double, C.c_int32, C.c_size_t,
                   C.POINTER(handle)], code),
    "nlsim_frf_info": ([handle, C.POINTER(FrfInfo)], code),
    "nlsim_frf_response": ([handle, dbl_p, C.c_size_t], code),
}
for name, (args, res) in signatures.items():
    f = getattr(lib, name)
    f.argtypes = args
    f.restype = res


def check(rc, want=OK, what=""):
    if rc != want:
        msg = lib.nlsim_last_error().decode()
        sys.exit(f"{what}: code {rc}, expected {want}: {msg}")


def bad(what, rc, want):
    msg = lib.nlsim_last_error().decode()
    if rc != want or not msg:
        sys.exit(f"bad call {what}: code {rc} (expected {want}), message '{msg}'")
    print("bad", what, rc, msg)


def values(key, xs):
    print(key, " ".join(repr(float(x)) for x in xs))


def doubles(xs):
    return (C.c_double * len(xs))(*xs)


def int64s(xs):
    return (C.c_int64 * len(xs))(*xs)


print("version", lib.nlsim_version().decode())

k = Sparse(0, 0, 0, int64s([0, 2, 4]), int64s([0, 1, 0, 1]), doubles([2e4, -1e4, -1e4, 1e4]))
m = Sparse(1, 1, 1, int64s([1, 2, 3]), int64s([1, 2]), doubles([1.0, 1.0]))
labels = (C.c_char_p * 2)(b"1:u", b"2:u")
model = handle()
check(lib.nlsim_model_new(b"chain", 2, labels, C.byref(m), C.byref(k), C.byref(model)))
check(lib.nlsim_model_set_rayleigh(model, 2.0, 0.0))
check(lib.nlsim_model_add_element(model, b"tip", b"cubic k3=1e9", b"2:u", None))
check(lib.nlsim_model_add_excitation(model, b"shaker", b"2:u", 1.0))
check(lib.nlsim_model_add_sensor(model, b"tip_d", b"2:u", 0))
mi = ModelInfo()
check(lib.nlsim_model_info(model, C.byref(mi)))
print("model_info", mi.n_dofs, mi.n_elements, mi.n_inputs, mi.n_sensors, mi.n_params)

reduced = handle()
check(lib.nlsim_reduce(model, 2, 0, C.byref(reduced)))
freqs = (C.c_double * 2)()
check(lib.nlsim_reduced_frequencies(reduced, freqs, 2))
values("frequencies", freqs)

steps, dt = 2000, 1e-4
force = doubles([math.sin(2.0 * math.pi * 10.0 * i * dt) for i in range(steps + 1)])
tip = (C.c_double * (steps + 1))()
run = RunInfo()
check(lib.nlsim_simulate(reduced, dt, steps, force, steps + 1, tip, steps + 1, C.byref(run)))
print("run_info", run.status, run.samples)
values("simulate", [tip[500], tip[1000], tip[1500], tip[2000]])

hb = handle()
check(lib.nlsim_hb_new(reduced, 5, C.byref(hb)))
hi = HbInfo()
check(lib.nlsim_hb_info(hb, C.byref(hi)))
print("hb_info", hi.harmonics, hi.n_sensors, hi.n_inputs, hi.n_unknowns, hi.n_params)
per = 2 * hi.n_sensors * (hi.harmonics + 1)
y = (C.c_double * per)()
pi = PointInfo()
check(lib.nlsim_hb_point(hb, 12.0, 1.0, 1, y, per, C.byref(pi)))
print("point_info", pi.status, pi.stable)
values("point_12hz", y)
names = (C.c_char_p * 2)(b"tip.k3", b"mode1.zeta")
dy = (C.c_double * (2 * per))()
check(lib.nlsim_hb_sensitivities(hb, 12.0, 1.0, names, 2, None, 0, dy, 2 * per, None))
values("sens_12hz", dy)

frf = handle()
check(lib.nlsim_frf(hb, 8.0, 20.0, 1.0, 1, 0, C.byref(frf)))
fi = FrfInfo()
check(lib.nlsim_frf_info(frf, C.byref(fi)))
print("frf_info", fi.status, fi.n_points, fi.n_folds)
fy = (C.c_double * (fi.n_points * per))()
check(lib.nlsim_frf_response(frf, fy, fi.n_points * per))
values("frf_last", fy[(fi.n_points - 1) * per:])

k3 = C.c_double()
check(lib.nlsim_get_param(hb, b"tip.k3", C.byref(k3)))
print("k3", repr(k3.value))
check(lib.nlsim_set_param(hb, b"tip.k3", 2e9))
check(lib.nlsim_hb_point(hb, 12.0, 1.0, 0, y, per, None))
values("point_12hz_k3x2", y)

file_model = handle()
check(lib.nlsim_model_load(f"{examples}/models/two_dof.toml".encode(), C.byref(file_model)))
fmi = ModelInfo()
check(lib.nlsim_model_info(file_model, C.byref(fmi)))
print("file_model", fmi.n_dofs, fmi.n_elements, fmi.n_inputs, fmi.n_sensors, fmi.n_params)

none = handle()
bad("null_out", lib.nlsim_model_new(b"x", 2, labels, C.byref(m), C.byref(k), None), ERR_NULL)
bad("unknown_dof", lib.nlsim_model_add_sensor(model, b"s", b"9:u", 0), ERR_INPUT)
bad("bad_law", lib.nlsim_model_add_element(model, b"e", b"cubic k9=1", b"1:u", None),
    ERR_INPUT)
one_dof = (C.c_char_p * 1)(b"1:u")
bad("coupled_dofs", lib.nlsim_model_add_coupled_element(
    model, b"g", b"coupled_polynomial k1_1_1=1 k2_2_0=2", one_dof, 1), ERR_INPUT)
bad("unknown_param", lib.nlsim_get_param(hb, b"tip.k4", C.byref(k3)), ERR_INPUT)
bad("wrong_size", lib.nlsim_hb_point(hb, 12.0, 1.0, 0, y, per - 1, None), ERR_SIZE)
bad("null_buffer", lib.nlsim_hb_point(hb, 12.0, 1.0, 0, None, per, None), ERR_NULL)
bad("wrong_kind", lib.nlsim_hb_point(reduced, 12.0, 1.0, 0, y, per, None), ERR_HANDLE)
bad("missing_file", lib.nlsim_model_load(b"/nonexistent/model.toml", C.byref(none)), ERR_IO)

check(lib.nlsim_free(frf))
bad("use_after_free", lib.nlsim_frf_info(frf, C.byref(fi)), ERR_HANDLE)
bad("double_free", lib.nlsim_free(frf), ERR_HANDLE)
for h in (hb, reduced, model, file_model):
    check(lib.nlsim_free(h))
live = C.c_size_t(99)
check(lib.nlsim_live_handles(C.byref(live)))
print("live_handles", live.value)
print("failures 0")
