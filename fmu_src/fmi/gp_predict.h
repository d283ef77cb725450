/* GP prediction at one input, for the native models (narx_model.c, blimp_model.c): the kernel
 * row, the predictive mean and the latent predictive variance of a GP with the weighted
 * squared-exponential kernel (Rasmussen & Williams 2006, Alg. 2.1, lines 4-6, in standardised
 * units), written once (gp_predict.c) and compiled into every native FMU.
 *
 * A GP of m basis points X (m x d, by rows) in d standardised inputs predicts at x:
 *   xs = (x - input_mean) / input_scale
 *   k_i = sigma_f^2 exp(-sum_c w_c (xs_c - X_ic)^2)                 (fmu_src/fmi/runtime.py, kernel_rows)
 *   mean = k . weights,  latent variance = max(sigma_f^2 - |V k|^2, 0)
 * with weights = alpha and V = L^-1 (exact GP; lower triangular) or the variance factor of a
 * sparse GP (full), so that |V k|^2 = k^T K^-1 k resp. its sparse counterpart.
 *
 * Storage of V (what the builders write into resources/model.bin, fmu_src/fmi/native.py,
 * packed_variance_factor): by columns; if lower triangular, column c holds only rows c .. m - 1
 * (m (m + 1) / 2 doubles in all), else rows 0 .. m - 1 (m x m). Columns, because v = V k is then
 * a sum of scaled columns: every row is independent (no long dependency chain) and the factor
 * streams from memory once, which is what a step costs when a model holds many factors.
 */
#ifndef FLIGHTGP_GP_PREDICT_H
#define FLIGHTGP_GP_PREDICT_H

#include <stddef.h>

/* Doubles a stored variance factor of m basis points takes. */
size_t gp_factor_size(int m, int lower_triangular);

/* xs = (x - input_mean) / input_scale, the input x (d) in the GP's standardised units. */
void gp_standardise(int d, const double *x, const double *input_mean, const double *input_scale, double *xs);

/* squared[i * d + c] = (xs_c - basis[i * d + c])^2 for i < m: the part of the kernel row that
 * every hyperparameter sample of a GP shares. */
void gp_squared_distances(int m, int d, const double *xs, const double *basis, double *squared);

/* k_i = exp(log_signal_variance - sum_c kernel_weights_c squared[i * d + c]), i < m. */
void gp_kernel_row(int m, int d, const double *squared, const double *kernel_weights, double log_signal_variance,
                   double *k);

/* sum_i k_i weights[i * stride], i < m, summed in order (stride: the number of outputs that
 * share the kernel row, weights by rows). */
double gp_mean(int m, const double *k, const double *weights, int stride);

/* max(signal_variance - |V k|^2, 0) (0 also for NaN), V stored as above; v: scratch (m). */
double gp_latent_variance(int m, const double *factor, int lower_triangular, const double *k, double signal_variance,
                          double *v);

/* max(second_moment - mean^2, 0), NaN kept (numpy.maximum): the variance of a mixture from its
 * mean and its mean second moment (law of total variance). */
double gp_spread(double second_moment, double mean);

#endif
