/* GP prediction at one input for the native models: gp_predict.h says what and why. */
#include <math.h>

#include "gp_predict.h"

size_t gp_factor_size(int m, int lower_triangular) {
    const size_t n = (size_t)m;
    return lower_triangular ? n * (n + 1) / 2 : n * n;
}

void gp_standardise(int d, const double *x, const double *input_mean, const double *input_scale, double *xs) {
    for (int c = 0; c < d; c++) xs[c] = (x[c] - input_mean[c]) / input_scale[c];
}

void gp_squared_distances(int m, int d, const double *xs, const double *basis, double *squared) {
    for (int i = 0; i < m; i++)
        for (int c = 0; c < d; c++) {
            const double difference = xs[c] - basis[(size_t)i * d + c];
            squared[(size_t)i * d + c] = difference * difference;
        }
}

void gp_kernel_row(int m, int d, const double *squared, const double *kernel_weights, double log_signal_variance,
                   double *k) {
    for (int i = 0; i < m; i++) {
        const double *row = squared + (size_t)i * d;
        double exponent = 0.0;
        for (int c = 0; c < d; c++) exponent += kernel_weights[c] * row[c];
        k[i] = exp(log_signal_variance - exponent);
    }
}

double gp_mean(int m, const double *k, const double *weights, int stride) {
    double mean = 0.0;
    for (int i = 0; i < m; i++) mean += k[i] * weights[(size_t)i * stride];
    return mean;
}

/* v = V k for V (m x m) stored by columns, four columns at a time (rows are independent: no
 * long dependency chain, and v is loaded and stored once per four columns). */
static void full_product(const double *factor, const double *k, int m, double *v) {
    int c = 0;
    for (int i = 0; i < m; i++) v[i] = 0.0;
    for (; c + 4 <= m; c += 4) {
        const double *c0 = factor + (size_t)c * m, *c1 = c0 + m, *c2 = c1 + m, *c3 = c2 + m;
        const double k0 = k[c], k1 = k[c + 1], k2 = k[c + 2], k3 = k[c + 3];
        for (int i = 0; i < m; i++) v[i] += c0[i] * k0 + c1[i] * k1 + c2[i] * k2 + c3[i] * k3;
    }
    for (; c < m; c++)
        for (int i = 0; i < m; i++) v[i] += factor[(size_t)c * m + i] * k[c];
}

/* v = V k for a lower triangular V stored by packed columns (column c: rows c .. m - 1). Each
 * v_i sums the same products in the same order as full_product, less the zeros above the
 * diagonal (adding 0 changes nothing), so both storages give the same doubles. */
static void lower_triangular_product(const double *factor, const double *k, int m, double *v) {
    const double *column = factor; /* column c */
    int c = 0;
    for (int i = 0; i < m; i++) v[i] = 0.0;
    for (; c + 4 <= m; c += 4) {
        /* columns c .. c + 3 start at rows c .. c + 3: entry of row i is cj[i - c - j] */
        const double *c0 = column, *c1 = c0 + (m - c), *c2 = c1 + (m - c - 1), *c3 = c2 + (m - c - 2);
        const double k0 = k[c], k1 = k[c + 1], k2 = k[c + 2], k3 = k[c + 3];
        v[c] += c0[0] * k0;
        v[c + 1] += c0[1] * k0 + c1[0] * k1;
        v[c + 2] += c0[2] * k0 + c1[1] * k1 + c2[0] * k2;
        const double *r0 = c0 + 3, *r1 = c1 + 2, *r2 = c2 + 1, *r3 = c3; /* row c + 3 */
        for (int i = 0; i < m - c - 3; i++) v[c + 3 + i] += r0[i] * k0 + r1[i] * k1 + r2[i] * k2 + r3[i] * k3;
        column = c3 + (m - c - 3);
    }
    for (; c < m; c++) {
        for (int i = c; i < m; i++) v[i] += column[i - c] * k[c];
        column += m - c;
    }
}

double gp_latent_variance(int m, const double *factor, int lower_triangular, const double *k, double signal_variance,
                          double *v) {
    if (lower_triangular) lower_triangular_product(factor, k, m, v);
    else full_product(factor, k, m, v);
    double explained = 0.0;
    for (int i = 0; i < m; i++) explained += v[i] * v[i];
    const double latent = signal_variance - explained;
    return latent > 0.0 ? latent : 0.0;
}

double gp_spread(double second_moment, double mean) {
    const double spread = second_moment - mean * mean;
    return spread > 0.0 || spread != spread ? spread : 0.0;
}
