/* Blimp RKGP (Ko, Klein, Fox and Haehnel, ICRA 2007, sec. IV-B) for a native FMU: the blimp ODE
 * integrated by RK4 plus the mean of a GP on its one-step residual, the lagged fan commands the
 * GP may see, and the state covariance propagated along the run. The same formulas, in the same
 * order, as the pythonfmu blimp RKGP FMU: validation/vehicles/blimp_equations.py (blimp_dynamics
 * and rk4_advance: Fossen's rigid body with added mass about the centre of buoyancy, gravity,
 * buoyancy, drag, gondola and tail thrust, fin lift; the equations and their sources are there),
 * fmu_src/blimp_rkgp/model.py (RKGPModel.gp_inputs, advance_lags and step) and
 * fmu_src/blimp_rkgp/slave.py (BlimpRKGP), whose module docstrings define the timing, the GP
 * inputs, the lagged commands, the standard deviations and the envelope. The residual GPs and the
 * covariance propagation are the FMI layer's greybox.c (greybox.h says how).
 *
 * Model constants. The physics (parameters, the mass matrix M = M_RB + M_A and its inverse,
 * computed by validation/vehicles/blimp_equations.py, mass_matrix, so that both FMUs use the same
 * doubles), the command lags, the propagation step, the GP structure, value references and
 * training envelope are compiled in from model_config.h; the GP arrays are read at
 * fmi2Instantiate from resources/DATA_FILE, written by fmu_src/blimp_rkgp/native.py: 8 bytes
 * "FGPBLMP2", the number of doubles that follow (uint64, little-endian, as the doubles), the GP
 * parts as greybox.h lays them out. Each instance reads its own copy (no memory shared between
 * instances).
 *
 * GP input x = [s[STATE_COLUMNS], u_gondola, mu, u_tail, h, z] (RKGPModel.gp_inputs).
 *
 * Lagged commands z (N_LAGS = N_COMMAND_LAGS x N_LAG_FANS; for each time constant T each fan
 * command u, LAG_COMMAND_COLUMNS): z(k+1) = a z(k) + (1 - a) u(k), a = exp(-h / T), from 0 at
 * the start (Franklin, Powell & Workman 1998, sec. 4.3; fmu_src/blimp_rkgp/model.py).
 *
 * Propagation (GreyBoxGP.propagate; greybox.h, "Step"): g(s) = RK4(s, u, h) + E[residual | s, u,
 * h, z]; the dynamics do not read the position, so physics_step advances the moved copies of
 * x, y, z by the centre's increments in the same order (the same doubles as a full RK4).
 *
 * Hidden state (MODEL_STATE_SIZE doubles, saved with the FMU state): the 12 states, their
 * covariance P (12 x 12, by rows), the lagged commands z (N_LAGS), then 1.0 while a GP input is
 * outside the training envelope (a warning is logged once per excursion).
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "greybox.h"
#include "model.h"
#include "model_config.h"

#define DATA_MAGIC "FGPBLMP2"
/* Indices in the hidden state */
#define COVARIANCE N_STATES
#define LAGS (COVARIANCE + N_STATES * N_STATES)
#define OUTSIDE_ENVELOPE (LAGS + N_LAGS)
#define LAG_SLOTS (N_LAGS > 0 ? N_LAGS : 1) /* ISO C has no zero-length arrays */
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

static void cross(const double a[3], const double b[3], double out[3]) {
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
}

/* d state / dt (validation/vehicles/blimp_equations.py, blimp_dynamics; Ko et al.
 * 2007 sec. III in Fossen's form). state: x, y, z, phi, theta, psi, U, V, W, P, Q, R;
 * commands: u_gondola, mu, u_tail. */
static void dynamics(const double state[N_STATES], const double commands[N_INPUTS], double out[N_STATES]) {
    const double *angles = state + 3, *nu = state + 6, *v = nu, *w = nu + 3;
    const double sf = sin(angles[0]), cf = cos(angles[0]);
    const double st = sin(angles[1]), ct = cos(angles[1]);
    const double sp = sin(angles[2]), cp = cos(angles[2]);
    /* body-to-earth rotation (ZYX Euler angles) */
    const double rotation[9] = {cp * ct, -sp * cf + cp * st * sf, sp * sf + cp * cf * st,
                                sp * ct, cp * cf + sf * st * sp, -cp * sf + st * sp * cf,
                                -st, ct * sf, ct * cf};
    for (int i = 0; i < 3; i++)
        out[i] = rotation[3 * i] * v[0] + rotation[3 * i + 1] * v[1] + rotation[3 * i + 2] * v[2];
    const double tt = tan(angles[1]);
    const double p = w[0], q = w[1], r = w[2];
    out[3] = p + sf * tt * q + cf * tt * r;
    out[4] = cf * q - sf * r;
    out[5] = (sf * q + cf * r) / ct;

    double momentum[6]; /* M nu: linear, then angular momentum */
    for (int i = 0; i < 6; i++) {
        double sum = 0.0;
        for (int j = 0; j < 6; j++) sum += nu[j] * MASS_MATRIX[6 * i + j];
        momentum[i] = sum;
    }
    const double down[3] = {-sin(angles[1]), cos(angles[1]) * sin(angles[0]), cos(angles[1]) * cos(angles[0])};
    const double weight = MASS * STANDARD_GRAVITY;

    const double u_gondola = commands[0], mu = commands[1], u_tail = commands[2];
    const double gondola = u_gondola * (u_gondola >= 0 ? GONDOLA_THRUST_FORWARD : GONDOLA_THRUST_BACKWARD);
    const double tail = u_tail * (u_tail >= 0 ? TAIL_THRUST_POSITIVE : TAIL_THRUST_NEGATIVE);
    const double thrust_force[3] = {gondola * cos(mu), -tail, -gondola * sin(mu)};
    const double thrust_moment[3] = {0.0, GONDOLA_ARM * gondola * cos(mu), TAIL_ARM * tail};
    const double fin_gain = FIN_LIFT * fabs(v[0]);
    const double fin_side = -fin_gain * (v[1] - TAIL_ARM * w[2]);
    const double fin_normal = -fin_gain * (v[2] + TAIL_ARM * w[1]);
    const double fin_force[3] = {0.0, fin_side, fin_normal};
    const double fin_moment[3] = {0.0, TAIL_ARM * fin_normal, -TAIL_ARM * fin_side};

    double weight_down[3], gravity_moment[3], w_x_momentum[3], v_x_momentum[3], w_x_angular[3];
    for (int i = 0; i < 3; i++) weight_down[i] = weight * down[i];
    cross(CG_POSITION, weight_down, gravity_moment);
    cross(w, momentum, w_x_momentum);
    cross(v, momentum, v_x_momentum);
    cross(w, momentum + 3, w_x_angular);
    double generalised_force[6];
    for (int i = 0; i < 3; i++) {
        generalised_force[i] = thrust_force[i] + fin_force[i] - NET_LIFT * down[i] - LINEAR_DRAG[i] * v[i]
                               - QUADRATIC_DRAG[i] * fabs(v[i]) * v[i] - w_x_momentum[i];
        generalised_force[3 + i] = thrust_moment[i] + fin_moment[i] + gravity_moment[i]
                                   - ROTATIONAL_DAMPING[i] * w[i] - v_x_momentum[i] - w_x_angular[i];
    }
    for (int i = 0; i < 6; i++) { /* nu_dot = M^-1 tau */
        double sum = 0.0;
        for (int j = 0; j < 6; j++) sum += generalised_force[j] * INVERSE_MASS_MATRIX[6 * i + j];
        out[6 + i] = sum;
    }
}

/* The commands and the step over which the physics holds them. */
typedef struct {
    const double *commands;
    double h;
} Held;

/* RK4 over dt in equal substeps no longer than MAX_STEP, commands held
 * (validation/vehicles/blimp_equations.py, rk4_advance; the 1e-9 is its SUBSTEP_ROUNDING). If
 * unread is not NULL, unread[c] and unread[N_UNREAD + c] (c = x, y, z) are advanced by the same
 * increments as state[c]: the RK4 steps of starts that differ from start only in position, which
 * the dynamics do not read (greybox.h, GreyBoxPhysics). */
static void physics_step(const void *context, const double *start, double *state, double *unread) {
    const Held *held = context;
    const double *commands = held->commands, dt = held->h;
    double n_sub = ceil(dt / MAX_STEP - 1e-9);
    if (!(n_sub > 1.0)) n_sub = 1.0;
    const double h = dt / n_sub;
    double k1[N_STATES], k2[N_STATES], k3[N_STATES], k4[N_STATES], probe[N_STATES];
    memcpy(state, start, sizeof(double) * N_STATES);
    for (long step = 0; step < (long)n_sub; step++) {
        dynamics(state, commands, k1);
        for (int i = 0; i < N_STATES; i++) probe[i] = state[i] + 0.5 * h * k1[i];
        dynamics(probe, commands, k2);
        for (int i = 0; i < N_STATES; i++) probe[i] = state[i] + 0.5 * h * k2[i];
        dynamics(probe, commands, k3);
        for (int i = 0; i < N_STATES; i++) probe[i] = state[i] + h * k3[i];
        dynamics(probe, commands, k4);
        for (int i = 0; i < N_STATES; i++) {
            const double increment = h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
            if (unread != NULL && i < N_UNREAD) {
                unread[i] = unread[i] + increment;
                unread[N_UNREAD + i] = unread[N_UNREAD + i] + increment;
            }
            state[i] = state[i] + increment;
        }
    }
}

/* The GP input [s[STATE_COLUMNS], u_gondola, mu, u_tail, h, z] (RKGPModel.gp_inputs). */
static void gp_input(const double s[N_STATES], const double commands[N_INPUTS], double h, const double *lags,
                     double x[N_GP_INPUTS]) {
    for (int c = 0; c < N_STATE_COLUMNS; c++) x[c] = s[STATE_COLUMNS[c]];
    for (int c = 0; c < N_INPUTS; c++) x[N_STATE_COLUMNS + c] = commands[c];
    x[N_STATE_COLUMNS + N_INPUTS] = h;
    for (int c = 0; c < N_LAGS; c++) x[N_STATE_COLUMNS + N_INPUTS + 1 + c] = lags[c];
}

/* z(k+1) = a z(k) + (1 - a) u(k), a = exp(-h / T) (RKGPModel.advance_lags). */
static void advance_lags(const double *lags, const double commands[N_INPUTS], double h, double *next) {
    for (int j = 0; j < N_COMMAND_LAGS; j++) {
        const double decay = exp(-h / LAG_TIME_CONSTANTS[j]);
        for (int f = 0; f < N_LAG_FANS; f++) {
            const int i = j * N_LAG_FANS + f;
            next[i] = decay * lags[i] + (1.0 - decay) * commands[LAG_COMMAND_COLUMNS[f]];
        }
    }
}

void model_start(Model *model, double *values, double *state) {
    (void)model;
    /* The start state: the <state>_start parameters (GreyBoxSlave.start_model), known (covariance
       0); the lagged commands 0 (fans at rest). */
    for (int i = 0; i < N_STATES; i++) state[i] = values[START_VR[i]];
    for (int i = N_STATES; i < MODEL_STATE_SIZE; i++) state[i] = 0.0;
    greybox_outputs(N_STATES, state, state + COVARIANCE, STATE_VR, SD_VR, values);
}

char *model_advance(Model *model, const Slave *slave, double *values, double *state, double t, double h) {
    double commands[N_INPUTS], x[N_GP_INPUTS], next[N_STATES], covariance[N_STATES * N_STATES], lags[LAG_SLOTS];
    for (int c = 0; c < N_INPUTS; c++) commands[c] = values[INPUT_VR[c]];
    /* s(t + h) = RK4(s(t), u(t), h) + E[residual] and P(t + h) (RKGPModel.step), dt = h */
    const Held held = {commands, h};
    gp_input(state, commands, h, state + LAGS, x);
    greybox_step(&model->greybox, physics_step, &held, N_UNREAD, GP_INPUT_OF_STATE, PROPAGATION_STEP, state,
                 state + COVARIANCE, x, next, covariance);
    advance_lags(state + LAGS, commands, h, lags);
    char *problem = greybox_nonfinite(N_STATES, next, covariance, t + h);
    if (problem != NULL) return problem;
    /* Envelope (GreyBoxSlave.advance_model, FlightgpSlave.report_envelope): warn once per excursion. */
    const int outside = report_envelope(slave, x, N_GP_INPUTS, GP_INPUT_NAMES, ENVELOPE_LOW, ENVELOPE_HIGH,
                                        ENVELOPE_MARGIN, state[OUTSIDE_ENVELOPE] != 0.0, t + h,
                                        "its standard deviations grow");
    /* Commit only after everything that can fail. */
    memcpy(state, next, sizeof next);
    memcpy(state + COVARIANCE, covariance, sizeof covariance);
    for (int i = 0; i < N_LAGS; i++) state[LAGS + i] = lags[i];
    state[OUTSIDE_ENVELOPE] = outside ? 1.0 : 0.0;
    greybox_outputs(N_STATES, next, covariance, STATE_VR, SD_VR, values);
    return NULL;
}
