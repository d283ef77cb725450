/* Blimp RKGP (Ko, Klein, Fox and Haehnel, ICRA 2007, sec. IV-B) for a native FMU: the blimp ODE
 * integrated by RK4 plus the mean of a GP on its one-step residual, the lagged fan commands the
 * GP may see, and the state covariance propagated along the run. The same formulas, in the same
 * order, as the pythonfmu blimp RKGP FMU: validation/vehicles/blimp_equations.py (blimp_dynamics
 * and rk4_advance: Fossen's rigid body with added mass about the centre of buoyancy, gravity,
 * buoyancy, drag, gondola and tail thrust, fin lift; the equations and their sources are there),
 * fmu_src/blimp_rkgp/model.py (RKGPModel.residual, advance_lags and step) and
 * fmu_src/blimp_rkgp/slave.py (BlimpRKGP), whose module docstrings define the timing, the GP
 * inputs, the lagged commands, the standard deviations and the envelope.
 *
 * Model constants. The physics (parameters, the mass matrix M = M_RB + M_A and its inverse,
 * computed by validation/vehicles/blimp_equations.py, mass_matrix, so that both FMUs use the same
 * doubles), the command lags, the propagation step, the GP structure, value references and
 * training envelope are compiled in from model_config.h; the GP arrays are read at
 * fmi2Instantiate from resources/DATA_FILE, written by fmu_src/blimp_rkgp/native.py:
 *
 *   8 bytes  "FGPBLMP2"
 *   8 bytes  number of doubles that follow (uint64, little-endian, as the doubles)
 *   doubles  per GP part p (d = N_GP_INPUTS, m = BASIS_POINTS[p], q = PART_OUTPUTS[p]; all in
 *            standardised units): input_mean (d), input_scale (d), output_mean (q),
 *            output_scale (q), kernel_weights (d), log_signal_variance, log_noise_variance,
 *            basis (m x d, by rows), weights (m x q, by rows), variance factor V = L^-1 stored
 *            as gp_predict.h says (by columns, packed if LOWER_TRIANGULAR[p]).
 *
 * A shared GP is one part with q = 12; one GP per state is twelve parts with q = 1, in state
 * order. Each instance reads its own copy (no memory shared between instances).
 *
 * Residual of part p at GP input x = [s[STATE_COLUMNS], u_gondola, mu, u_tail, h, z]
 * (R&W 2006, Alg. 2.1, lines 4-6, in standardised units; the kernel row, means and latent
 * variance by the FMI layer's gp_predict.c):
 *   xs = (x - input_mean) / input_scale,  k_i = sigma_f^2 exp(-sum_c w_c (xs_c - basis_i,c)^2)
 *   mean_j = k . weights_j,  spread = max(sigma_f^2 - |V k|^2, 0) + sigma_n^2,
 *   var_j = max((spread + mean_j^2) - mean_j^2, 0)   (GaussianProcess.predict with include_noise,
 *   its one-component mixture, rounding included); in physical units mean_j output_scale_j +
 *   output_mean_j and var_j output_scale_j^2.
 *
 * Lagged commands z (N_LAGS = N_COMMAND_LAGS x N_LAG_FANS; for each time constant T each fan
 * command u, LAG_COMMAND_COLUMNS): z(k+1) = a z(k) + (1 - a) u(k), a = exp(-h / T), from 0 at
 * the start (Franklin, Powell & Workman 1998, sec. 4.3; fmu_src/blimp_rkgp/model.py).
 *
 * Propagation (GreyBoxGP.propagate; fmu_src/blimp_rkgp/model.py, "Standard deviations"): with
 * g(s) = RK4(s, u, h) + E[residual | s, u, h, z] and e_j the unit vectors,
 *   J e_j = (g(s + PROPAGATION_STEP e_j) - g(s - PROPAGATION_STEP e_j)) / (2 PROPAGATION_STEP),
 *   P(k+1) = (J P(k)) J^T + diag(var)   (var: the residuals' variances at s, noise included).
 * 25 evaluations of g, with two exact shortcuts: the dynamics do not read the position, so the
 * RK4 steps of s +/- step e_j for j = x, y, z are those of s, and the position alone is
 * advanced by the same increments in the same order (the same doubles as a full RK4); and a
 * state the GP does not see (GP_INPUT_OF_STATE < 0) leaves the GP input, so the GP mean, as it is.
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

#include "gp_predict.h"
#include "model.h"
#include "model_config.h"

#define DATA_MAGIC "FGPBLMP2"
/* Indices in the hidden state */
#define COVARIANCE N_STATES
#define LAGS (COVARIANCE + N_STATES * N_STATES)
#define OUTSIDE_ENVELOPE (LAGS + N_LAGS)
#define D N_GP_INPUTS
#define LAG_SLOTS (N_LAGS > 0 ? N_LAGS : 1) /* ISO C has no zero-length arrays */

/* One GP part (pointers into Model.data). */
typedef struct {
    int m, q, lower_triangular;
    const double *input_mean, *input_scale;  /* (d,) */
    const double *output_mean, *output_scale; /* (q,) */
    const double *kernel_weights;            /* (d,) */
    double log_signal_variance, signal_variance, noise_variance;
    const double *basis;                     /* (m, d) */
    const double *weights;                   /* (m, q) */
    const double *variance_factor;           /* by columns, packed if lower triangular (gp_predict.h) */
} GPPart;

struct Model {
    double *data;
    GPPart part[N_PARTS];
    double *squared;            /* scratch (m_max, d) */
    double *k, *v;              /* scratch (m_max,) */
};

void model_free(Model *model) {
    if (model == NULL) return;
    free(model->data);
    free(model->squared);
    free(model->k);
    free(model->v);
    free(model);
}

static Model *fail(Model *model, char **error, char *message) {
    *error = message;
    model_free(model);
    return NULL;
}

Model *model_load(const char *resources_dir, char **error) {
    Model *model = calloc(1, sizeof(Model));
    if (model == NULL) return fail(NULL, error, NULL);
    model->data = read_model_data(resources_dir, DATA_MAGIC, DATA_DOUBLES, error);
    if (model->data == NULL) return fail(model, error, *error);
    /* Point every part into the data (layout above). */
    const double *p = model->data;
    int m_max = 1;
    for (int j = 0; j < N_PARTS; j++) {
        GPPart *part = &model->part[j];
        part->m = BASIS_POINTS[j];
        part->q = PART_OUTPUTS[j];
        part->lower_triangular = LOWER_TRIANGULAR[j];
        const size_t m = (size_t)part->m, q = (size_t)part->q;
        part->input_mean = p, p += D;
        part->input_scale = p, p += D;
        part->output_mean = p, p += q;
        part->output_scale = p, p += q;
        part->kernel_weights = p, p += D;
        part->log_signal_variance = *p++;
        part->signal_variance = exp(part->log_signal_variance);
        part->noise_variance = exp(*p++);
        part->basis = p, p += m * D;
        part->weights = p, p += m * q;
        part->variance_factor = p, p += gp_factor_size(part->m, part->lower_triangular);
        if (part->m > m_max) m_max = part->m;
    }
    model->squared = malloc(sizeof(double) * (size_t)m_max * D);
    model->k = malloc(sizeof(double) * (size_t)m_max);
    model->v = malloc(sizeof(double) * (size_t)m_max);
    if (model->squared == NULL || model->k == NULL || model->v == NULL) return fail(model, error, NULL);
    return model;
}

/* Means of the 12 residuals at GP input x and, if var is not NULL, their predictive variances
 * with the observation noise (RKGPModel.residual): per part the kernel row, the means and
 * GaussianProcess.predict's one-component mixture variance max((spread + mean^2) - mean^2, 0)
 * of spread = latent + noise (gp_predict.c). */
static void residual(const Model *model, const double x[D], double mean[N_STATES], double var[N_STATES]) {
    int out = 0;
    for (int j = 0; j < N_PARTS; j++) {
        const GPPart *part = &model->part[j];
        const int m = part->m, q = part->q;
        double xs[D];
        gp_standardise(D, x, part->input_mean, part->input_scale, xs);
        gp_squared_distances(m, D, xs, part->basis, model->squared);
        gp_kernel_row(m, D, model->squared, part->kernel_weights, part->log_signal_variance, model->k);
        const double spread = var == NULL ? 0.0
            : gp_latent_variance(m, part->variance_factor, part->lower_triangular, model->k, part->signal_variance,
                                 model->v) + part->noise_variance;
        for (int o = 0; o < q; o++) {
            const double mu = gp_mean(m, model->k, part->weights + o, q);
            mean[out] = mu * part->output_scale[o] + part->output_mean[o];
            if (var != NULL) var[out] = gp_spread(spread + mu * mu, mu) * (part->output_scale[o] * part->output_scale[o]);
            out++;
        }
    }
}

static void cross(const double a[3], const double b[3], double out[3]) {
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
}

/* d state / dt (validation/vehicles/blimp_equations.py, blimp_dynamics; Ko et al.
 * 2007 sec. III in Fossen's form). state: x, y, z, phi, theta, psi, U, V, W, P, Q, R;
 * commands: u_gondola, mu, u_tail. */
static void dynamics(const double state[N_STATES], const double commands[3], double out[N_STATES]) {
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

/* RK4 over dt in equal substeps no longer than MAX_STEP, commands held
 * (validation/vehicles/blimp_equations.py, rk4_advance; the 1e-9 is its SUBSTEP_ROUNDING). If
 * positions is not NULL, positions[0][c] and positions[1][c] (c = x, y, z) are advanced by the
 * same increments as state[c]: the RK4 steps of starts that differ from start only in position,
 * which the dynamics do not read (the propagation's shortcut, header). */
static void physics_step(const double start[N_STATES], const double commands[3], double dt,
                         double state[N_STATES], double positions[2][3]) {
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
            if (positions != NULL && i < 3) {
                positions[0][i] = positions[0][i] + increment;
                positions[1][i] = positions[1][i] + increment;
            }
            state[i] = state[i] + increment;
        }
    }
}

/* The GP input [s[STATE_COLUMNS], u_gondola, mu, u_tail, h, z] (RKGPModel.gp_inputs). */
static void gp_input(const double s[N_STATES], const double commands[3], double h, const double *lags, double x[D]) {
    for (int c = 0; c < N_STATE_COLUMNS; c++) x[c] = s[STATE_COLUMNS[c]];
    for (int c = 0; c < 3; c++) x[N_STATE_COLUMNS + c] = commands[c];
    x[N_STATE_COLUMNS + 3] = h;
    for (int c = 0; c < N_LAGS; c++) x[N_STATE_COLUMNS + 4 + c] = lags[c];
}

/* z(k+1) = a z(k) + (1 - a) u(k), a = exp(-h / T) (RKGPModel.advance_lags). */
static void advance_lags(const double *lags, const double commands[3], double h, double *next) {
    for (int j = 0; j < N_COMMAND_LAGS; j++) {
        const double decay = exp(-h / LAG_TIME_CONSTANTS[j]);
        for (int f = 0; f < N_LAG_FANS; f++) {
            const int i = j * N_LAG_FANS + f;
            next[i] = decay * lags[i] + (1.0 - decay) * commands[LAG_COMMAND_COLUMNS[f]];
        }
    }
}

/* One step of the mean and its covariance (RKGPModel.step; header, "Propagation"): next (12),
 * covariance (12 x 12, by rows) from state and P, the GP input x at the state (for the envelope). */
static void propagate(const Model *model, const double state[N_STATES], const double P[N_STATES * N_STATES],
                      const double commands[3], double h, const double *lags, double next[N_STATES],
                      double covariance[N_STATES * N_STATES], double x[D]) {
    double mean[N_STATES], var[N_STATES], physics[N_STATES], positions[2][3];
    double plus[N_STATES], minus[N_STATES], J[N_STATES * N_STATES], JP[N_STATES * N_STATES];
    gp_input(state, commands, h, lags, x);
    residual(model, x, mean, var);
    for (int c = 0; c < 3; c++) {
        positions[0][c] = state[c] + PROPAGATION_STEP;
        positions[1][c] = state[c] - PROPAGATION_STEP;
    }
    physics_step(state, commands, h, physics, positions);
    for (int i = 0; i < N_STATES; i++) next[i] = physics[i] + mean[i];
    for (int j = 0; j < N_STATES; j++) { /* column j of J */
        for (int sign = 0; sign < 2; sign++) {
            double *moved = sign == 0 ? plus : minus;
            double probe[N_STATES], moved_mean[N_STATES];
            memcpy(probe, state, sizeof probe);
            probe[j] = state[j] + (sign == 0 ? PROPAGATION_STEP : -PROPAGATION_STEP);
            if (j < 3) { /* the dynamics do not read the position: the centre's steps */
                memcpy(moved, physics, sizeof physics);
                moved[j] = positions[sign][j];
            } else {
                physics_step(probe, commands, h, moved, NULL);
            }
            if (GP_INPUT_OF_STATE[j] >= 0) { /* the GP sees state j */
                double probe_x[D];
                memcpy(probe_x, x, sizeof probe_x);
                probe_x[GP_INPUT_OF_STATE[j]] = probe[j];
                residual(model, probe_x, moved_mean, NULL);
            } else {
                memcpy(moved_mean, mean, sizeof moved_mean);
            }
            for (int i = 0; i < N_STATES; i++) moved[i] = moved[i] + moved_mean[i];
        }
        for (int i = 0; i < N_STATES; i++) J[i * N_STATES + j] = (plus[i] - minus[i]) / (2 * PROPAGATION_STEP);
    }
    for (int i = 0; i < N_STATES; i++) /* J P */
        for (int c = 0; c < N_STATES; c++) {
            double sum = 0.0;
            for (int r = 0; r < N_STATES; r++) sum += J[i * N_STATES + r] * P[r * N_STATES + c];
            JP[i * N_STATES + c] = sum;
        }
    for (int i = 0; i < N_STATES; i++) /* (J P) J^T + diag(var) */
        for (int c = 0; c < N_STATES; c++) {
            double sum = 0.0;
            for (int r = 0; r < N_STATES; r++) sum += JP[i * N_STATES + r] * J[c * N_STATES + r];
            covariance[i * N_STATES + c] = i == c ? sum + var[i] : sum;
        }
}

/* The outputs: the states and the square roots of the covariance's diagonal, negative rounding
 * clipped (PropagatedRollout.sd). */
static void set_outputs(double *values, const double state[N_STATES], const double covariance[N_STATES * N_STATES]) {
    for (int i = 0; i < N_STATES; i++) {
        const double variance = covariance[i * N_STATES + i];
        values[STATE_VR[i]] = state[i];
        values[SD_VR[i]] = sqrt(variance > 0.0 ? variance : 0.0);
    }
}

void model_start(Model *model, double *values, double *state) {
    (void)model;
    /* The start state: the <state>_start parameters (BlimpRKGP.start_model), known (covariance
       0); the lagged commands 0 (fans at rest). */
    for (int i = 0; i < N_STATES; i++) state[i] = values[START_VR[i]];
    for (int i = N_STATES; i < MODEL_STATE_SIZE; i++) state[i] = 0.0;
    set_outputs(values, state, state + COVARIANCE);
}

char *model_advance(Model *model, const Slave *slave, double *values, double *state, double t, double h) {
    double commands[3], x[D], next[N_STATES], covariance[N_STATES * N_STATES], lags[LAG_SLOTS];
    for (int c = 0; c < 3; c++) commands[c] = values[COMMAND_VR[c]];
    /* s(t + h) = RK4(s(t), u(t), h) + E[residual] and P(t + h) (RKGPModel.step), dt = h */
    propagate(model, state, state + COVARIANCE, commands, h, state + LAGS, next, covariance, x);
    advance_lags(state + LAGS, commands, h, lags);
    int finite = 1;
    for (int i = 0; i < N_STATES; i++) finite = finite && isfinite(next[i]);
    for (int i = 0; i < N_STATES * N_STATES; i++) finite = finite && isfinite(covariance[i]);
    if (!finite) {
        double variances[N_STATES];
        for (int i = 0; i < N_STATES; i++) variances[i] = covariance[i * N_STATES + i];
        char *s = number_list(next, N_STATES), *v = number_list(variances, N_STATES);
        char *message = format_message("non-finite state %s (variances %s) at t = %.16g s", s ? s : "?",
                                       v ? v : "?", t + h);
        free(s), free(v);
        return message != NULL ? message : format_message("non-finite state");
    }
    /* Envelope (BlimpRKGP.advance_model, FlightgpSlave.report_envelope): warn once per excursion. */
    char *outside = envelope_excursions(x, D, GP_INPUT_NAMES, ENVELOPE_LOW, ENVELOPE_HIGH, ENVELOPE_MARGIN);
    const int was_outside = state[OUTSIDE_ENVELOPE] != 0.0;
    if (outside != NULL && !was_outside)
        slave_log(slave, fmi2Warning, "t = %.16g s: input outside the training envelope: %s. The GP extrapolates; "
                  "its standard deviations grow.", t + h, outside);
    else if (outside == NULL && was_outside)
        slave_log(slave, fmi2OK, "t = %.16g s: back inside the training envelope", t + h);
    /* Commit only after everything that can fail. */
    memcpy(state, next, sizeof next);
    memcpy(state + COVARIANCE, covariance, sizeof covariance);
    for (int i = 0; i < N_LAGS; i++) state[LAGS + i] = lags[i];
    state[OUTSIDE_ENVELOPE] = outside != NULL ? 1.0 : 0.0;
    free(outside);
    set_outputs(values, next, covariance);
    return NULL;
}
