/* A C caller of libnlsim_c: builds the 2-DOF cubic chain of examples/two_dof_cubic.rs from
 * CSR arrays, reduces it, simulates it, solves harmonic-balance points, follows an FRF with
 * sensitivities, reads and sets parameters, calibrates k3 against data it computes itself,
 * and makes deliberately bad calls. It prints `key value...` lines that capi/tests/foreign.rs
 * compares with the Rust API; it exits non-zero on the first unexpected code. */

#include "nlsim.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static int failures = 0;

/* Calls `call` and stops the program unless it returns `want`. */
#define EXPECT(want, call)                                                                  \
  do {                                                                                      \
    NlsimCode rc_ = (call);                                                                 \
    if (rc_ != (want)) {                                                                    \
      fprintf(stderr, "%s:%d: %s returned %d, expected %d: %s\n", __FILE__, __LINE__,      \
              #call, (int)rc_, (int)(want), nlsim_last_error());                            \
      exit(2);                                                                              \
    }                                                                                       \
  } while (0)

#define OK(call) EXPECT(NLSIM_CODE_OK, call)

/* A bad call: it must return `want` and leave a message. */
static void bad(const char *what, NlsimCode got, NlsimCode want) {
  const char *msg = nlsim_last_error();
  if (got != want || msg == NULL || msg[0] == '\0') {
    fprintf(stderr, "bad call %s: code %d (expected %d), message '%s'\n", what, (int)got,
            (int)want, msg ? msg : "(null)");
    failures++;
  }
  printf("bad %s %d %s\n", what, (int)got, msg);
}

static void print_values(const char *key, const double *v, size_t n) {
  printf("%s", key);
  for (size_t i = 0; i < n; i++) printf(" %.17g", v[i]);
  printf("\n");
}

int main(void) {
  printf("version %s\n", nlsim_version());

  /* K = [[2e4, -1e4], [-1e4, 1e4]] N/m as both triangles in CSR; M = I kg as its lower
   * triangle in CSC with Fortran indices. */
  const int64_t k_ptr[] = {0, 2, 4};
  const int64_t k_idx[] = {0, 1, 0, 1};
  const double k_val[] = {2e4, -1e4, -1e4, 1e4};
  const int64_t m_ptr[] = {1, 2, 3};
  const int64_t m_idx[] = {1, 2};
  const double m_val[] = {1.0, 1.0};
  NlsimSparse k = {NLSIM_STORAGE_CSR, 0, 0, k_ptr, k_idx, k_val};
  NlsimSparse m = {NLSIM_STORAGE_CSC, 1, 1, m_ptr, m_idx, m_val};
  const char *labels[] = {"1:u", "2:u"};

  NlsimModel model = 0;
  OK(nlsim_model_new("chain", 2, labels, &m, &k, &model));
  OK(nlsim_model_set_rayleigh(model, 2.0, 0.0));
  OK(nlsim_model_add_element(model, "tip", "cubic k3=1e9", "2:u", NULL));
  OK(nlsim_model_add_excitation(model, "shaker", "2:u", 1.0));
  OK(nlsim_model_add_sensor(model, "tip_d", "2:u", NLSIM_QUANTITY_DISPLACEMENT));
  NlsimModelInfo mi;
  OK(nlsim_model_info(model, &mi));
  printf("model_info %zu %zu %zu %zu %zu\n", mi.n_dofs, mi.n_elements, mi.n_inputs,
         mi.n_sensors, mi.n_params);

  /* Parameter names, with the size query first. */
  for (size_t i = 0; i < mi.n_params; i++) {
    size_t need = 0;
    EXPECT(NLSIM_CODE_ERR_SIZE, nlsim_param_name(model, i, NULL, 0, &need));
    char *name = malloc(need);
    OK(nlsim_param_name(model, i, name, need, &need));
    printf("model_param %zu %s\n", i, name);
    free(name);
  }

  NlsimReduced reduced = 0;
  OK(nlsim_reduce(model, 2, 0, &reduced));
  size_t n_modes = 0;
  OK(nlsim_reduced_n_modes(reduced, &n_modes));
  double freqs[2];
  OK(nlsim_reduced_frequencies(reduced, freqs, n_modes));
  print_values("frequencies", freqs, n_modes);

  /* 0.2 s of a 1 N, 10 Hz sine sampled at 10 kHz. */
  enum { STEPS = 2000 };
  const double dt = 1e-4;
  double *force = malloc(sizeof(double) * (STEPS + 1));
  for (int i = 0; i <= STEPS; i++) force[i] = sin(2.0 * M_PI * 10.0 * i * dt);
  double *tip = malloc(sizeof(double) * (STEPS + 1));
  NlsimRunInfo run;
  OK(nlsim_simulate(reduced, dt, STEPS, force, STEPS + 1, tip, STEPS + 1, &run));
  printf("run_info %d %zu\n", run.status, run.samples);
  const double picks[] = {tip[500], tip[1000], tip[1500], tip[2000]};
  print_values("simulate", picks, 4);

  /* Harmonic balance with H = 5 at 12 Hz, with stability. */
  NlsimHb hb = 0;
  OK(nlsim_hb_new(reduced, 5, &hb));
  NlsimHbInfo hi;
  OK(nlsim_hb_info(hb, &hi));
  printf("hb_info %zu %zu %zu %zu %zu\n", hi.harmonics, hi.n_sensors, hi.n_inputs,
         hi.n_unknowns, hi.n_params);
  const size_t per = 2 * hi.n_sensors * (hi.harmonics + 1);
  double y[12];
  NlsimPointInfo pi;
  OK(nlsim_hb_point(hb, 12.0, 1.0, 1, y, per, &pi));
  printf("point_info %d %d\n", pi.status, pi.stable);
  print_values("point_12hz", y, per);

  const char *names[] = {"tip.k3", "mode1.zeta"};
  double dy[24];
  OK(nlsim_hb_sensitivities(hb, 12.0, 1.0, names, 2, NULL, 0, dy, 2 * per, NULL));
  print_values("sens_12hz", dy, 2 * per);

  /* The FRF from 8 to 20 Hz, its last point and the sensitivities there. */
  NlsimFrf frf = 0;
  OK(nlsim_frf(hb, 8.0, 20.0, 1.0, 1, 0, &frf));
  NlsimFrfInfo fi;
  OK(nlsim_frf_info(frf, &fi));
  printf("frf_info %d %zu %zu\n", fi.status, fi.n_points, fi.n_folds);
  double *ff = malloc(sizeof(double) * fi.n_points);
  double *fy = malloc(sizeof(double) * fi.n_points * per);
  double *fd = malloc(sizeof(double) * fi.n_points * per * 2);
  int32_t *stable = malloc(sizeof(int32_t) * fi.n_points);
  int32_t *fold = malloc(sizeof(int32_t) * fi.n_points);
  OK(nlsim_frf_frequencies(frf, ff, fi.n_points));
  OK(nlsim_frf_response(frf, fy, fi.n_points * per));
  OK(nlsim_frf_stability(frf, stable, fold, fi.n_points));
  OK(nlsim_frf_sensitivities(frf, names, 2, fd, fi.n_points * per * 2));
  size_t last = fi.n_points - 1, n_stable = 0, n_fold = 0;
  for (size_t i = 0; i < fi.n_points; i++) {
    n_stable += stable[i] == 1;
    n_fold += fold[i] == 1;
  }
  printf("frf_counts %zu %zu\n", n_stable, n_fold);
  const double ends[] = {ff[0], ff[last]};
  print_values("frf_ends", ends, 2);
  print_values("frf_last", fy + last * per, per);
  print_values("frf_sens_last", fd + last * per * 2, per * 2);

  /* Parameters on the system: set k3 to 2e9, solve again, set it back. */
  double k3 = 0.0;
  OK(nlsim_get_param(hb, "tip.k3", &k3));
  printf("k3 %.17g\n", k3);
  OK(nlsim_set_param(hb, "tip.k3", 2e9));
  OK(nlsim_hb_point(hb, 12.0, 1.0, 0, y, per, NULL));
  print_values("point_12hz_k3x2", y, per);
  OK(nlsim_set_param(hb, "tip.k3", 1e9));

  /* Calibration of k3 against the system's own fundamental, 1 % noise, off the band
   * 9.5-16 Hz where the response has three branches. */
  enum { NS = 7 };
  const double cf[NS] = {5.0, 6.5, 8.0, 9.0, 17.0, 18.5, 20.0};
  double cforce[NS * 2], cresp[NS * 2];
  for (int s = 0; s < NS; s++) {
    OK(nlsim_hb_point(hb, cf[s], 1.0, 0, y, per, NULL));
    cforce[2 * s] = 1.0;
    cforce[2 * s + 1] = 0.0;
    cresp[2 * s] = y[2]; /* harmonic 1 of the only sensor */
    cresp[2 * s + 1] = y[3];
  }
  NlsimTestData data = 0;
  OK(nlsim_testdata_new("shaker", 1, &data));
  OK(nlsim_testdata_add_channel(data, "tip_d", NLSIM_QUANTITY_DISPLACEMENT, 0.0, 0.01));
  OK(nlsim_testdata_add_sweep(data, "up", 0, NS, cf, cforce, NS * 2, cresp, NS * 2));
  OK(nlsim_set_param(hb, "tip.k3", 3e9));
  NlsimCalibrationSettings cs = nlsim_calibration_settings_default();
  cs.lhs_samples = 8;
  cs.starts = 1;
  cs.folds = 0;
  const char *cal_names[] = {"tip.k3"};
  const double lo[] = {1e8}, hi_[] = {1e10};
  double est[1], sd[1];
  NlsimCalibrationInfo ci;
  OK(nlsim_calibrate(hb, data, cal_names, 1, lo, hi_, &cs, est, sd, &ci));
  printf("calibration %.17g %.17g %d\n", est[0], sd[0], ci.status);

  /* The same calibration with its cancel flag raised before it starts (as a signal handler
   * would raise it): stopped at its first safe point, the system's own value in est, NaN in
   * sd. */
  int32_t cancel = 1;
  cs.cancel = &cancel;
  bad("cancelled", nlsim_calibrate(hb, data, cal_names, 1, lo, hi_, &cs, est, sd, &ci),
      NLSIM_CODE_STOPPED_SHORT);
  if (!(est[0] == 3e9 && isnan(sd[0]))) {
    fprintf(stderr, "cancelled calibration: est %g sd %g\n", est[0], sd[0]);
    failures++;
  }
  cs.cancel = NULL;

  /* The same data recorded as the amplifier's voltage (0.4 V for 1 N: an input gain of
   * 2.5 N/V, calibrated beside k3), each step weighed by its own standard deviations (1 % of
   * the response per part). */
  double vforce[NS * 2], vsig[NS * 2];
  for (int s = 0; s < NS; s++) {
    vforce[2 * s] = 0.4;
    vforce[2 * s + 1] = 0.0;
    vsig[2 * s] = vsig[2 * s + 1] = 0.01 * hypot(cresp[2 * s], cresp[2 * s + 1]);
  }
  NlsimTestData vdata = 0;
  OK(nlsim_testdata_new("shaker", 1, &vdata));
  OK(nlsim_testdata_set_record(vdata, 1));
  OK(nlsim_testdata_add_channel(vdata, "tip_d", NLSIM_QUANTITY_DISPLACEMENT, 0.0, 0.01));
  bad("sigma_size", nlsim_testdata_add_sweep_sigma(vdata, "up", 0, NS, cf, vforce, NS * 2, cresp,
                                                   NS * 2, vsig, NS), NLSIM_CODE_ERR_SIZE);
  OK(nlsim_testdata_add_sweep_sigma(vdata, "up", 0, NS, cf, vforce, NS * 2, cresp, NS * 2, vsig,
                                    NS * 2));
  bad("bad_record", nlsim_testdata_set_record(vdata, 7), NLSIM_CODE_ERR_INPUT);
  const char *gain_names[] = {"tip.k3", "input_gain"};
  const double glo[] = {1e8, 0.5}, ghi[] = {1e10, 10.0};
  double gest[2], gsd[2];
  OK(nlsim_calibrate(hb, vdata, gain_names, 2, glo, ghi, &cs, gest, gsd, &ci));
  printf("gain_calibration %.17g %.17g %.17g %.17g %.17g %d\n", gest[0], gest[1], gsd[0], gsd[1],
         ci.chi2_scale, ci.misfit_warning);
  OK(nlsim_free(vdata));

  /* A model file. */
  NlsimModel file_model = 0;
  OK(nlsim_model_load(NLSIM_EXAMPLES "/models/two_dof.toml", &file_model));
  NlsimModelInfo fmi;
  OK(nlsim_model_info(file_model, &fmi));
  printf("file_model %zu %zu %zu %zu %zu\n", fmi.n_dofs, fmi.n_elements, fmi.n_inputs,
         fmi.n_sensors, fmi.n_params);

  /* Deliberately bad calls: an error code and a message, never a crash. */
  NlsimModel none = 0;
  bad("null_out", nlsim_model_new("x", 2, labels, &m, &k, NULL), NLSIM_CODE_ERR_NULL);
  bad("null_name", nlsim_model_new(NULL, 2, labels, &m, &k, &none), NLSIM_CODE_ERR_NULL);
  bad("asymmetric", nlsim_model_new("x", 2, NULL, &m,
                                    &(NlsimSparse){NLSIM_STORAGE_CSR, 0, 0, k_ptr, k_idx,
                                                   (const double[]){2e4, -1e4, -2e4, 1e4}},
                                    &none),
      NLSIM_CODE_ERR_INPUT);
  bad("index_outside", nlsim_model_new("x", 2, NULL, &m,
                                       &(NlsimSparse){NLSIM_STORAGE_CSR, 0, 0, k_ptr,
                                                      (const int64_t[]){0, 1, 0, 7}, k_val},
                                       &none),
      NLSIM_CODE_ERR_INPUT);
  bad("unknown_dof", nlsim_model_add_sensor(model, "s", "9:u", 0), NLSIM_CODE_ERR_INPUT);
  bad("bad_quantity", nlsim_model_add_sensor(model, "s", "1:u", 7), NLSIM_CODE_ERR_INPUT);
  const char *one_dof[] = {"1:u"};
  bad("coupled_dofs",
      nlsim_model_add_coupled_element(model, "g", "coupled_polynomial k1_1_1=1 k2_2_0=2",
                                      one_dof, 1),
      NLSIM_CODE_ERR_INPUT);
  bad("bad_law", nlsim_model_add_element(model, "e", "cubic k9=1", "1:u", NULL),
      NLSIM_CODE_ERR_INPUT);
  bad("unknown_param", nlsim_get_param(hb, "tip.k4", &k3), NLSIM_CODE_ERR_INPUT);
  bad("nan_param", nlsim_set_param(model, "tip.k3", NAN), NLSIM_CODE_ERR_INPUT);
  bad("wrong_size", nlsim_hb_point(hb, 12.0, 1.0, 0, y, per - 1, NULL), NLSIM_CODE_ERR_SIZE);
  bad("null_buffer", nlsim_hb_point(hb, 12.0, 1.0, 0, NULL, per, NULL), NLSIM_CODE_ERR_NULL);
  bad("bad_frequency", nlsim_hb_point(hb, -1.0, 1.0, 0, y, per, NULL), NLSIM_CODE_ERR_INPUT);
  bad("wrong_kind", nlsim_hb_point(reduced, 12.0, 1.0, 0, y, per, NULL), NLSIM_CODE_ERR_HANDLE);
  bad("handle_zero", nlsim_reduce(0, 2, 0, &none), NLSIM_CODE_ERR_HANDLE);
  bad("forged_handle", nlsim_free(0x7fffffffffffULL), NLSIM_CODE_ERR_HANDLE);
  bad("missing_file", nlsim_model_load("/nonexistent/model.toml", &none), NLSIM_CODE_ERR_IO);
  bad("force_length", nlsim_simulate(reduced, dt, STEPS, force, STEPS + 1, tip, STEPS, NULL),
      NLSIM_CODE_ERR_SIZE);

  /* Every handle freed exactly once; a second free and a use after free are refused. */
  OK(nlsim_free(frf));
  bad("use_after_free", nlsim_frf_info(frf, &fi), NLSIM_CODE_ERR_HANDLE);
  bad("double_free", nlsim_free(frf), NLSIM_CODE_ERR_HANDLE);
  OK(nlsim_free(data));
  OK(nlsim_free(hb));
  OK(nlsim_free(reduced));
  OK(nlsim_free(model));
  OK(nlsim_free(file_model));
  size_t live = 99;
  OK(nlsim_live_handles(&live));
  printf("live_handles %zu\n", live);

  free(force);
  free(tip);
  free(ff);
  free(fy);
  free(fd);
  free(stable);
  free(fold);
  printf("failures %d\n", failures);
  return failures == 0 ? 0 : 1;
}
