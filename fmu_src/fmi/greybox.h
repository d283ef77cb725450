/* What every native grey-box (RKGP) model shares (blimp_model.c, rgblimp_model.c): the residual
 * GPs read from the model data, their means and variances at one input, one step of the mean and
 * of the first-order covariance propagation, and the outputs. The same formulas, in the same order,
 * as the pythonfmu grey-box FMUs' fmu_src/fmi/greybox.py (ResidualGPs, FirstOrderPropagation,
 * GreyBoxSlave), whose module docstring defines them; written once (greybox.c) and compiled into
 * every native FMU. Dimensions are arguments, so this file needs no model_config.h.
 *
 * Residual GPs: one part shared by all n states (q = n outputs) or one per state (q = 1 each, in
 * state order). The model data (resources/model.bin, fmu_src/fmi/greybox_build.py,
 * greybox_doubles) holds per part p (d GP inputs, m = basis_points[p], q = part_outputs[p]; all in
 * standardised units): input_mean (d), input_scale (d), output_mean (q), output_scale (q),
 * kernel_weights (d), log_signal_variance, log_noise_variance, basis (m x d, by rows), weights
 * (m x q, by rows), variance factor V = L^-1 stored as gp_predict.h says (by columns, packed if
 * lower_triangular[p]).
 *
 * Residual of part p at GP input x (R&W 2006, Alg. 2.1, lines 4-6, in standardised units; the
 * kernel row, means and latent variance by gp_predict.c):
 *   xs = (x - input_mean) / input_scale,  k_i = sigma_f^2 exp(-sum_c w_c (xs_c - basis_i,c)^2)
 *   mean_j = k . weights_j,  spread = max(sigma_f^2 - |V k|^2, 0) + sigma_n^2,
 *   var_j = max((spread + mean_j^2) - mean_j^2, 0)   (GaussianProcess.predict with include_noise,
 *   its one-component mixture, rounding included); in physical units mean_j output_scale_j +
 *   output_mean_j and var_j output_scale_j^2.
 *
 * Step (GreyBoxGP.propagate): with g(s) = physics(s) + E[residual | x(s)] and e_j the unit
 * vectors,
 *   J e_j = (g(s + step e_j) - g(s - step e_j)) / (2 step),
 *   P(k+1) = (J P(k)) J^T + diag(var)   (var: the residuals' variances at s, noise included),
 * 2 n + 1 evaluations of g, with two exact shortcuts: the first n_unread states (the position)
 * are read by neither the physics nor the GP, so the physics step of s +/- step e_j for those j is
 * that of s with state j alone advanced by the same increments (the model's physics advances the
 * moved copies it is given, "unread" below); and a state the GP does not see
 * (gp_input_of_state[j] < 0) leaves the GP input, so the GP mean, as it is.
 */
#ifndef FLIGHTGP_GREYBOX_H
#define FLIGHTGP_GREYBOX_H

#include <stddef.h>

/* One residual GP part (pointers into the model data). */
typedef struct {
    int m, q, lower_triangular;
    const double *input_mean, *input_scale;   /* (d,) */
    const double *output_mean, *output_scale; /* (q,) */
    const double *kernel_weights;             /* (d,) */
    double log_signal_variance, signal_variance, noise_variance;
    const double *basis;                      /* (m, d) */
    const double *weights;                    /* (m, q) */
    const double *variance_factor;            /* by columns, packed if lower triangular (gp_predict.h) */
} ResidualPart;

/* A grey-box model's residual GPs and the scratch memory of its steps (one per FMU instance). */
typedef struct {
    int n_states, n_inputs, n_parts;
    ResidualPart *part;
    double *xs, *squared, *k, *v; /* prediction scratch: (d,), (m_max, d), (m_max,), (m_max,) */
    double *work;                 /* step scratch */
} GreyBox;

/* The physics step of one state: next = physics(start); if unread is not NULL, unread[c] and
 * unread[n_unread + c] (c < n_unread) are advanced by the same increments as state c (header). */
typedef void (*GreyBoxPhysics)(const void *context, const double *start, double *next, double *unread);

/* Doubles of the model data the parts take (layout above). */
size_t greybox_data_size(int n_inputs, int n_parts, const int *basis_points, const int *part_outputs,
                         const int *lower_triangular);

/* Point the n_parts parts of n_states residuals in n_inputs GP inputs into data (layout above,
 * greybox_data_size doubles) and allocate the scratch memory. Returns 0, or -1 when out of
 * memory (then greybox_free releases what was allocated). */
int greybox_init(GreyBox *greybox, const double *data, int n_states, int n_inputs, int n_parts,
                 const int *basis_points, const int *part_outputs, const int *lower_triangular);

void greybox_free(GreyBox *greybox);

/* Means of the n_states residuals at GP input x and, if var is not NULL, their predictive
 * variances with the observation noise (header; ResidualGPs.predict). */
void greybox_residual(const GreyBox *greybox, const double *x, double *mean, double *var);

/* One step of the mean and its covariance (header, "Step"; FirstOrderPropagation): next (n) and
 * next_covariance (n x n, by rows) from state and covariance, x the GP input at state, step the
 * central-difference step; gp_input_of_state (n) each state's index in x, -1 if the GP does not
 * see it; physics and context the model's physics step, whose first n_unread states it does
 * not read. */
void greybox_step(const GreyBox *greybox, GreyBoxPhysics physics, const void *context, int n_unread,
                  const int *gp_input_of_state, double step, const double *state, const double *covariance,
                  const double *x, double *next, double *next_covariance);

/* next_covariance = (J P) J^T + diag(var) (n x n, by rows; FirstOrderPropagation.advance), JP
 * scratch (n x n). */
void covariance_update(int n, const double *J, const double *covariance, const double *var, double *JP,
                       double *next_covariance);

/* NULL if next (n) and covariance (n x n) are finite; else a message for the refused step at time
 * t (malloc'd). */
char *greybox_nonfinite(int n, const double *next, const double *covariance, double t);

/* The outputs: values[state_vr[i]] = state[i] and values[sd_vr[i]] the square root of the
 * covariance's diagonal, negative rounding clipped (GreyBoxSlave, PropagatedRollout.sd). */
void greybox_outputs(int n, const double *state, const double *covariance, const unsigned *state_vr,
                     const unsigned *sd_vr, double *values);

#endif
