/* Residual GPs and the covariance propagation of the native grey-box models: greybox.h says what
 * and why. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "gp_predict.h"
#include "greybox.h"
#include "model.h"

size_t greybox_data_size(int n_inputs, int n_parts, const int *basis_points, const int *part_outputs,
                         const int *lower_triangular) {
    size_t total = 0;
    const size_t d = (size_t)n_inputs;
    for (int p = 0; p < n_parts; p++) {
        const size_t m = (size_t)basis_points[p], q = (size_t)part_outputs[p];
        total += 3 * d + 2 * q + 2 + m * d + m * q + gp_factor_size(basis_points[p], lower_triangular[p]);
    }
    return total;
}

int greybox_init(GreyBox *greybox, const double *data, int n_states, int n_inputs, int n_parts,
                 const int *basis_points, const int *part_outputs, const int *lower_triangular) {
    memset(greybox, 0, sizeof *greybox);
    greybox->n_states = n_states;
    greybox->n_inputs = n_inputs;
    greybox->n_parts = n_parts;
    greybox->part = calloc((size_t)n_parts, sizeof(ResidualPart));
    if (greybox->part == NULL) return -1;
    const size_t d = (size_t)n_inputs, n = (size_t)n_states;
    const double *p = data;
    int m_max = 1;
    for (int j = 0; j < n_parts; j++) { /* point every part into the data (layout: greybox.h) */
        ResidualPart *part = &greybox->part[j];
        part->m = basis_points[j];
        part->q = part_outputs[j];
        part->lower_triangular = lower_triangular[j];
        const size_t m = (size_t)part->m, q = (size_t)part->q;
        part->input_mean = p, p += d;
        part->input_scale = p, p += d;
        part->output_mean = p, p += q;
        part->output_scale = p, p += q;
        part->kernel_weights = p, p += d;
        part->log_signal_variance = *p++;
        part->signal_variance = exp(part->log_signal_variance);
        part->noise_variance = exp(*p++);
        part->basis = p, p += m * d;
        part->weights = p, p += m * q;
        part->variance_factor = p, p += gp_factor_size(part->m, part->lower_triangular);
        if (part->m > m_max) m_max = part->m;
    }
    greybox->xs = malloc(sizeof(double) * d);
    greybox->squared = malloc(sizeof(double) * (size_t)m_max * d);
    greybox->k = malloc(sizeof(double) * (size_t)m_max);
    greybox->v = malloc(sizeof(double) * (size_t)m_max);
    /* step scratch (greybox_step): 9 vectors of n, one of d, two n x n matrices */
    greybox->work = malloc(sizeof(double) * (9 * n + d + 2 * n * n));
    if (greybox->xs == NULL || greybox->squared == NULL || greybox->k == NULL || greybox->v == NULL
        || greybox->work == NULL)
        return -1;
    return 0;
}

void greybox_free(GreyBox *greybox) {
    free(greybox->part);
    free(greybox->xs);
    free(greybox->squared);
    free(greybox->k);
    free(greybox->v);
    free(greybox->work);
    memset(greybox, 0, sizeof *greybox);
}

void greybox_residual(const GreyBox *greybox, const double *x, double *mean, double *var) {
    const int d = greybox->n_inputs;
    int out = 0;
    for (int j = 0; j < greybox->n_parts; j++) {
        const ResidualPart *part = &greybox->part[j];
        const int m = part->m, q = part->q;
        gp_standardise(d, x, part->input_mean, part->input_scale, greybox->xs);
        gp_squared_distances(m, d, greybox->xs, part->basis, greybox->squared);
        gp_kernel_row(m, d, greybox->squared, part->kernel_weights, part->log_signal_variance, greybox->k);
        const double spread = var == NULL ? 0.0
            : gp_latent_variance(m, part->variance_factor, part->lower_triangular, greybox->k, part->signal_variance,
                                 greybox->v) + part->noise_variance;
        for (int o = 0; o < q; o++) {
            const double mu = gp_mean(m, greybox->k, part->weights + o, q);
            mean[out] = mu * part->output_scale[o] + part->output_mean[o];
            if (var != NULL) var[out] = gp_spread(spread + mu * mu, mu) * (part->output_scale[o] * part->output_scale[o]);
            out++;
        }
    }
}

void greybox_step(const GreyBox *greybox, GreyBoxPhysics physics, const void *context, int n_unread,
                  const int *gp_input_of_state, double step, const double *state, const double *covariance,
                  const double *x, double *next, double *next_covariance) {
    const int n = greybox->n_states, d = greybox->n_inputs;
    double *mean = greybox->work, *var = mean + n, *centre = var + n, *plus = centre + n, *minus = plus + n;
    double *probe = minus + n, *moved_mean = probe + n, *unread = moved_mean + n; /* unread: 2 n */
    double *probe_x = unread + 2 * n, *J = probe_x + d, *JP = J + n * n;
    greybox_residual(greybox, x, mean, var);
    for (int c = 0; c < n_unread; c++) {
        unread[c] = state[c] + step;
        unread[n_unread + c] = state[c] - step;
    }
    physics(context, state, centre, unread);
    for (int i = 0; i < n; i++) next[i] = centre[i] + mean[i];
    for (int j = 0; j < n; j++) { /* column j of J */
        for (int sign = 0; sign < 2; sign++) {
            double *moved = sign == 0 ? plus : minus;
            memcpy(probe, state, sizeof(double) * (size_t)n);
            probe[j] = state[j] + (sign == 0 ? step : -step);
            if (j < n_unread) { /* the physics does not read state j: the centre's steps */
                memcpy(moved, centre, sizeof(double) * (size_t)n);
                moved[j] = unread[sign * n_unread + j];
            } else {
                physics(context, probe, moved, NULL);
            }
            if (gp_input_of_state[j] >= 0) { /* the GP sees state j */
                memcpy(probe_x, x, sizeof(double) * (size_t)d);
                probe_x[gp_input_of_state[j]] = probe[j];
                greybox_residual(greybox, probe_x, moved_mean, NULL);
            } else {
                memcpy(moved_mean, mean, sizeof(double) * (size_t)n);
            }
            for (int i = 0; i < n; i++) moved[i] = moved[i] + moved_mean[i];
        }
        for (int i = 0; i < n; i++) J[i * n + j] = (plus[i] - minus[i]) / (2 * step);
    }
    covariance_update(n, J, covariance, var, JP, next_covariance);
}

void covariance_update(int n, const double *J, const double *covariance, const double *var, double *JP,
                       double *next_covariance) {
    for (int i = 0; i < n; i++) /* J P */
        for (int c = 0; c < n; c++) {
            double sum = 0.0;
            for (int r = 0; r < n; r++) sum += J[i * n + r] * covariance[r * n + c];
            JP[i * n + c] = sum;
        }
    for (int i = 0; i < n; i++) /* (J P) J^T + diag(var) */
        for (int c = 0; c < n; c++) {
            double sum = 0.0;
            for (int r = 0; r < n; r++) sum += JP[i * n + r] * J[c * n + r];
            next_covariance[i * n + c] = i == c ? sum + var[i] : sum;
        }
}

char *greybox_nonfinite(int n, const double *next, const double *covariance, double t) {
    int finite = 1;
    for (int i = 0; i < n; i++) finite = finite && isfinite(next[i]);
    for (int i = 0; i < n * n; i++) finite = finite && isfinite(covariance[i]);
    if (finite) return NULL;
    double *variances = malloc(sizeof(double) * (size_t)n);
    if (variances != NULL)
        for (int i = 0; i < n; i++) variances[i] = covariance[i * n + i];
    char *s = number_list(next, n), *v = variances != NULL ? number_list(variances, n) : NULL;
    char *message = format_message("non-finite state %s (variances %s) at t = %.16g s", s ? s : "?", v ? v : "?", t);
    free(s), free(v), free(variances);
    return message != NULL ? message : format_message("non-finite state");
}

void greybox_outputs(int n, const double *state, const double *covariance, const unsigned *state_vr,
                     const unsigned *sd_vr, double *values) {
    for (int i = 0; i < n; i++) {
        const double variance = covariance[i * n + i];
        values[state_vr[i]] = state[i];
        values[sd_vr[i]] = sqrt(variance > 0.0 ? variance : 0.0);
    }
}
