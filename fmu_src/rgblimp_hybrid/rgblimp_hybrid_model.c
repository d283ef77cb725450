/* RGBlimp hybrid for a native FMU: the identified RGBlimp model (rgblimp_physics.c, which
 * rgblimp_physics.h describes) with the rollout-trained correction of its body accelerations added
 * in every RK4 stage, stepped over one 1/60 s sample, and the covariance of the state and the
 * band's random acceleration propagated along the run to first order. The same formulas, in the
 * same order, as the pythonfmu RGBlimp hybrid FMU: validation/models/rgblimp_hybrid_step.py
 * (Correction, air_features, hybrid_step), fmu_src/rgblimp_hybrid/model.py (RGBlimpHybridModel:
 * start_covariance, step) and fmu_src/rgblimp_hybrid/slave.py (RGBlimpHybrid), whose module
 * docstrings define the correction, the timing, the standard deviations and the envelope.
 *
 * Correction at the air-frame state s and the inputs u with the thrust factor applied:
 *   z_c = features_c(s, u) / FEATURE_SCALE_c   (U V W P Q R phi theta thrust_left thrust_right gondola_x)
 *   a_o = amplitude_o * sum_i exp(-1/2 sum_c ((z_c - inducing_ic) / length_scale_c)^2) weights_io
 * plus, in the covariance propagation, the random acceleration d (the augmented states 12..17).
 *
 * Propagation (FirstOrderPropagation.advance over the 18 augmented states, greybox.h "Step"
 * without GPs): g(s, d) = (hybrid step of s with d added to the accelerations, DECAY d); J by
 * central differences of PROPAGATION_STEP; P(k+1) = J P(k) J^T + diag(PROCESS_NOISE); P(0) =
 * diag(0, DISTURBANCE_VARIANCE). The mean of d stays 0. As in greybox_step, the physics step of the
 * moved copies of x, y, z (which the dynamics do not read) is the centre's with the one coordinate
 * advanced by the same increments (the same doubles as a full step).
 *
 * Model data, read at fmi2Instantiate from resources/DATA_FILE (written by
 * fmu_src/rgblimp_hybrid/native.py): 8 bytes "FGPRGBH1", the number of doubles that follow (uint64,
 * little-endian, as the doubles), then inducing (N_INDUCING x N_FEATURES, by rows), weights
 * (N_INDUCING x 6, by rows), length_scale (N_FEATURES), amplitude (6). Each instance reads its own
 * copy.
 *
 * Hidden state (MODEL_STATE_SIZE doubles, saved with the FMU state): the 12 states, the augmented
 * covariance (18 x 18, by rows), then 1.0 while a feature is outside the fitting envelope (a warning
 * is logged once per excursion).
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "greybox.h"
#include "model.h"
#include "model_config.h"
#include "rgblimp_physics.h"

#define DATA_MAGIC "FGPRGBH1"
/* Indices in the hidden state */
#define COVARIANCE N_STATES
#define OUTSIDE_ENVELOPE (COVARIANCE + N_AUGMENTED * N_AUGMENTED)
/* The states the dynamics do not read: the position x, y, z */
#define N_UNREAD 3
#define N_DISTURBANCES (N_AUGMENTED - N_STATES)

struct Model {
    double *data;
    const double *inducing, *weights, *length_scale, *amplitude;
};

/* What the extra acceleration sees: the correction and the random acceleration over the step. */
typedef struct {
    const Model *model;
    const double *disturbance; /* (6,) */
} Extra;

/* The augmented step's context: the held inputs (their extra_context set per call). */
typedef struct {
    const Model *model;
    RGBlimpHeld held;
} Augmented;

void model_free(Model *model) {
    if (model == NULL) return;
    free(model->data);
    free(model);
}

Model *model_load(const char *resources_dir, char **error) {
    Model *model = calloc(1, sizeof(Model));
    *error = NULL;
    if (model == NULL) return NULL;
    model->data = read_model_data(resources_dir, DATA_MAGIC, DATA_DOUBLES, error);
    if (model->data == NULL) {
        model_free(model);
        return NULL;
    }
    model->inducing = model->data;
    model->weights = model->inducing + N_INDUCING * N_FEATURES;
    model->length_scale = model->weights + N_INDUCING * 6;
    model->amplitude = model->length_scale + N_FEATURES;
    return model;
}

/* The features (physical units) of the state s and the inputs u (rgblimp_hybrid_step.py, features;
 * the columns STATE_FEATURES, INPUT_FEATURES from model_config.h). */
static void features(const double s[N_STATES], const double u[N_INPUTS], double z[N_FEATURES]) {
    const int n_state = (int)(sizeof STATE_FEATURES / sizeof STATE_FEATURES[0]);
    for (int c = 0; c < n_state; c++) z[c] = s[STATE_FEATURES[c]];
    for (int c = n_state; c < N_FEATURES; c++) z[c] = u[INPUT_FEATURES[c - n_state]];
}

/* ExtraAcceleration: the correction (Correction.__call__) plus the random acceleration. */
static void correction(const void *context, const double s[N_STATES], const double u[N_INPUTS], double out[6]) {
    const Extra *extra = context;
    const Model *model = extra->model;
    double z[N_FEATURES], sum[6] = {0.0, 0.0, 0.0, 0.0, 0.0, 0.0};
    features(s, u, z);
    for (int c = 0; c < N_FEATURES; c++) z[c] = z[c] / FEATURE_SCALE[c];
    for (int i = 0; i < N_INDUCING; i++) {
        double squared = 0.0;
        for (int c = 0; c < N_FEATURES; c++) {
            const double scaled = (z[c] - model->inducing[i * N_FEATURES + c]) / model->length_scale[c];
            squared += scaled * scaled;
        }
        const double k = exp(-0.5 * squared);
        for (int o = 0; o < 6; o++) sum[o] += k * model->weights[i * 6 + o];
    }
    for (int o = 0; o < 6; o++) out[o] = model->amplitude[o] * sum[o] + extra->disturbance[o];
}

/* The augmented step (GreyBoxPhysics): the hybrid step of the 12 states with the random
 * acceleration start[12..17] added, and that acceleration times DECAY. */
static void augmented_step(const void *context, const double *start, double *next, double *unread) {
    const Augmented *augmented = context;
    const Extra extra = {augmented->model, start + N_STATES};
    RGBlimpHeld held = augmented->held;
    held.extra_context = &extra;
    rgblimp_step(&held, start, next, unread);
    for (int i = N_STATES; i < N_AUGMENTED; i++) next[i] = DECAY * start[i];
}

/* The outputs: the states and the square roots of the first 12 variances (GreyBoxSlave._set_outputs). */
static void set_outputs(const double *state, const double *covariance, double *values) {
    for (int i = 0; i < N_STATES; i++) {
        const double variance = covariance[i * N_AUGMENTED + i];
        values[STATE_VR[i]] = state[i];
        values[SD_VR[i]] = sqrt(variance > 0.0 ? variance : 0.0);
    }
}

void model_start(Model *model, double *values, double *state) {
    (void)model;
    /* The start state: the <state>_start parameters, known; the random acceleration stationary
     * (RGBlimpHybridModel.start_covariance). */
    for (int i = 0; i < N_STATES; i++) state[i] = values[START_VR[i]];
    for (int i = N_STATES; i < MODEL_STATE_SIZE; i++) state[i] = 0.0;
    for (int i = 0; i < N_DISTURBANCES; i++)
        state[COVARIANCE + (N_STATES + i) * N_AUGMENTED + N_STATES + i] = DISTURBANCE_VARIANCE[i];
    set_outputs(state, state + COVARIANCE, values);
}

char *model_advance(Model *model, const Slave *slave, double *values, double *state, double t, double h) {
    double inputs[N_INPUTS], centre[N_AUGMENTED], moved[2][N_AUGMENTED], probe[N_AUGMENTED];
    double unread[2 * N_UNREAD], J[N_AUGMENTED * N_AUGMENTED], JP[N_AUGMENTED * N_AUGMENTED];
    double covariance[N_AUGMENTED * N_AUGMENTED], air[N_STATES], x[N_FEATURES];
    Augmented augmented = {model, {{0.0}, NULL, NULL}};
    for (int c = 0; c < N_INPUTS; c++) inputs[c] = values[INPUT_VR[c]];
    rgblimp_hold(&augmented.held, inputs, correction, NULL);
    /* The centre: the state with the random acceleration at its mean, 0. */
    double mean[N_AUGMENTED];
    memcpy(mean, state, sizeof(double) * N_STATES);
    for (int i = N_STATES; i < N_AUGMENTED; i++) mean[i] = 0.0;
    for (int c = 0; c < N_UNREAD; c++) {
        unread[c] = mean[c] + PROPAGATION_STEP;
        unread[N_UNREAD + c] = mean[c] - PROPAGATION_STEP;
    }
    augmented_step(&augmented, mean, centre, unread);
    for (int j = 0; j < N_AUGMENTED; j++) { /* column j of J (FirstOrderPropagation.advance) */
        for (int sign = 0; sign < 2; sign++) {
            if (j < N_UNREAD) { /* the dynamics do not read state j: the centre's steps */
                memcpy(moved[sign], centre, sizeof centre);
                moved[sign][j] = unread[sign * N_UNREAD + j];
            } else {
                memcpy(probe, mean, sizeof mean);
                probe[j] = mean[j] + (sign == 0 ? PROPAGATION_STEP : -PROPAGATION_STEP);
                augmented_step(&augmented, probe, moved[sign], NULL);
            }
        }
        for (int i = 0; i < N_AUGMENTED; i++) J[i * N_AUGMENTED + j] = (moved[0][i] - moved[1][i]) / (2 * PROPAGATION_STEP);
    }
    covariance_update(N_AUGMENTED, J, state + COVARIANCE, PROCESS_NOISE, JP, covariance);
    char *problem = greybox_nonfinite(N_AUGMENTED, centre, covariance, t + h);
    if (problem != NULL) return problem;
    /* Envelope (GreyBoxSlave.advance_model): the features at the state (air_features), warn once
     * per excursion. */
    memcpy(air, state, sizeof air);
    rgblimp_add_wind_velocity(air, -1.0);
    features(air, augmented.held.inputs, x);
    const int outside = report_envelope(slave, x, N_FEATURES, FEATURE_NAMES, ENVELOPE_LOW, ENVELOPE_HIGH,
                                        ENVELOPE_MARGIN, state[OUTSIDE_ENVELOPE] != 0.0, t + h,
                                        "the correction fades to the physics there");
    /* Commit only after everything that can fail. */
    memcpy(state, centre, sizeof(double) * N_STATES);
    memcpy(state + COVARIANCE, covariance, sizeof covariance);
    state[OUTSIDE_ENVELOPE] = outside ? 1.0 : 0.0;
    set_outputs(centre, covariance, values);
    return NULL;
}
