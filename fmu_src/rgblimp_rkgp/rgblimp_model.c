/* RGBlimp RKGP for a native FMU: the identified RGBlimp model stepped by one classical RK4 step per
 * 1/60 s sample (rgblimp_physics.c, which rgblimp_physics.h describes), plus the mean of GPs on its
 * one-step residual, and the state covariance propagated along the run. The same formulas, in the
 * same order, as the pythonfmu RGBlimp RKGP FMU: fmu_src/rgblimp_rkgp/model.py
 * (RGBlimpRKGPModel.physics, gp_inputs and step) and fmu_src/rgblimp_rkgp/slave.py (RGBlimpRKGP),
 * whose module docstrings define the timing, the GP inputs, the standard deviations and the
 * envelope. The residual GPs and the covariance propagation are the FMI layer's greybox.c
 * (greybox.h says how).
 *
 * Model constants. The physics (rgblimp_physics.h), the propagation step, the GP structure, value
 * references and training envelope are compiled in from model_config.h; the GP arrays are read at
 * fmi2Instantiate from resources/DATA_FILE, written by fmu_src/rgblimp_rkgp/native.py: 8 bytes
 * "FGPRGBL1", the number of doubles that follow (uint64, little-endian, as the doubles), the GP
 * parts as greybox.h lays them out. Each instance reads its own copy (no memory shared between
 * instances).
 *
 * GP input x = [s[STATE_COLUMNS], thrust_left, thrust_right, gondola_x, gondola_y, gondola_z]
 * (RGBlimpRKGPModel.gp_inputs; the inputs as set, before the thrust factor).
 *
 * Propagation (GreyBoxGP.propagate; greybox.h, "Step"): g(s) = f(s, u) + E[residual | s, u];
 * rgblimp_step advances the moved copies of x, y, z by the centre's increments in the same order
 * (the same doubles as a full step).
 *
 * Hidden state (MODEL_STATE_SIZE doubles, saved with the FMU state): the 12 states, their
 * covariance P (12 x 12, by rows), then 1.0 while a GP input is outside the training envelope (a
 * warning is logged once per excursion).
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "greybox.h"
#include "model.h"
#include "model_config.h"
#include "rgblimp_physics.h"

#define DATA_MAGIC "FGPRGBL1"
/* Indices in the hidden state */
#define COVARIANCE N_STATES
#define OUTSIDE_ENVELOPE (COVARIANCE + N_STATES * N_STATES)
/* The states the dynamics do not read: the position x, y, z (greybox.h) */
#define N_UNREAD 3

struct Model {
    double *data;
    GreyBox greybox;
};

void model_free(Model *model) {
    if (model == NULL) return;
    greybox_free(&model->greybox);
    free(model->data);
    free(model);
}

Model *model_load(const char *resources_dir, char **error) {
    Model *model = calloc(1, sizeof(Model));
    *error = NULL;
    if (model == NULL) return NULL;
    model->data = read_model_data(resources_dir, DATA_MAGIC, DATA_DOUBLES, error);
    if (model->data == NULL
        || greybox_init(&model->greybox, model->data, N_STATES, N_GP_INPUTS, N_PARTS, BASIS_POINTS, PART_OUTPUTS,
                        LOWER_TRIANGULAR) != 0) {
        model_free(model);
        return NULL;
    }
    return model;
}

/* The GP input [s[STATE_COLUMNS], inputs] (RGBlimpRKGPModel.gp_inputs). */
static void gp_input(const double s[N_STATES], const double inputs[N_INPUTS], double x[N_GP_INPUTS]) {
    for (int c = 0; c < N_STATE_COLUMNS; c++) x[c] = s[STATE_COLUMNS[c]];
    for (int c = 0; c < N_INPUTS; c++) x[N_STATE_COLUMNS + c] = inputs[c];
}

void model_start(Model *model, double *values, double *state) {
    (void)model;
    /* The start state: the <state>_start parameters (GreyBoxSlave.start_model), known (covariance 0). */
    for (int i = 0; i < N_STATES; i++) state[i] = values[START_VR[i]];
    for (int i = N_STATES; i < MODEL_STATE_SIZE; i++) state[i] = 0.0;
    greybox_outputs(N_STATES, state, state + COVARIANCE, STATE_VR, SD_VR, values);
}

char *model_advance(Model *model, const Slave *slave, double *values, double *state, double t, double h) {
    double inputs[N_INPUTS], x[N_GP_INPUTS], next[N_STATES], covariance[N_STATES * N_STATES];
    RGBlimpHeld held;
    for (int c = 0; c < N_INPUTS; c++) inputs[c] = values[INPUT_VR[c]];
    rgblimp_hold(&held, inputs, NULL, NULL);
    /* s(t + h) = f(s(t), u(t)) + E[residual] and P(t + h) (RGBlimpRKGPModel.step); h = SAMPLE_TIME */
    gp_input(state, inputs, x);
    greybox_step(&model->greybox, rgblimp_step, &held, N_UNREAD, GP_INPUT_OF_STATE, PROPAGATION_STEP, state,
                 state + COVARIANCE, x, next, covariance);
    char *problem = greybox_nonfinite(N_STATES, next, covariance, t + h);
    if (problem != NULL) return problem;
    /* Envelope (GreyBoxSlave.advance_model, FlightgpSlave.report_envelope): warn once per excursion. */
    const int outside = report_envelope(slave, x, N_GP_INPUTS, GP_INPUT_NAMES, ENVELOPE_LOW, ENVELOPE_HIGH,
                                        ENVELOPE_MARGIN, state[OUTSIDE_ENVELOPE] != 0.0, t + h,
                                        "its standard deviations grow");
    /* Commit only after everything that can fail. */
    memcpy(state, next, sizeof next);
    memcpy(state + COVARIANCE, covariance, sizeof covariance);
    state[OUTSIDE_ENVELOPE] = outside ? 1.0 : 0.0;
    greybox_outputs(N_STATES, next, covariance, STATE_VR, SD_VR, values);
    return NULL;
}
