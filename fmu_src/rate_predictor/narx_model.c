/* GP-NARX rate predictor (Bo105 GP-NARX paper, AHS 74th Forum, 2018) for a native FMU: the
 * same formulas, in the same order where it matters, as fmu_src/rate_predictor/predictor.py
 * (NarxPredictor) and fmu_src/rate_predictor/slave.py (RatePredictor), whose docstrings define the timing, the
 * regressor order, the mixture over hyperparameter samples, the bounds and the envelope.
 *
 * Model constants. The structure (signals, lags, value references, training envelope, array
 * sizes) is compiled in from model_config.h; the GP arrays are read at fmi2Instantiate from
 * resources/DATA_FILE, written by fmu_src/rate_predictor/native.py:
 *
 *   8 bytes  "FGPNARX1"
 *   8 bytes  number of doubles that follow (uint64, native byte order)
 *   doubles  per output j (d = N_REGRESSORS, m = BASIS_POINTS[j], S = HYPERPARAMETER_SAMPLES[j]):
 *              input_mean (d), input_scale (d), output_mean, output_scale, basis (m x d),
 *              then per hyperparameter sample s:
 *                weights (m), kernel_weights (d), log_signal_variance, noise_variance,
 *                variance factor V_s stored as gp_predict.h says (by columns, packed if
 *                LOWER_TRIANGULAR[j]).
 *
 * Each instance reads its own copy (no memory shared between instances) and computes its own
 * free-run constants from it (prepare_free_run; A_s is S m^2 doubles per output, 10 MB for the
 * paper's 400-sample model).
 *
 * Prediction of output j at regressor x (all GP arrays in standardised units; each sample's
 * kernel row, mean and latent variance by the FMI layer's gp_predict.c):
 *   xs = (x - input_mean) / input_scale
 *   k_s,i = exp(log_signal_variance_s - sum_c w_s,c (xs_c - basis_i,c)^2)
 *   mu_s = k_s . weights_s,  var_s = max(sigma_f,s^2 - |V_s k_s|^2, 0) + noise_variance_s
 *   mean = E_s[mu_s], spread = max(E_s[var_s + mu_s^2] - mean^2, 0)   (law of total variance)
 *   output: mean * output_scale + output_mean, variance spread * output_scale^2.
 * V_s = L_s^-1 is lower triangular for an exact GP (LOWER_TRIANGULAR[j]); it is then stored and
 * multiplied without the zeros above the diagonal. The step's cost is dominated by streaming
 * the S variance factors from memory (the paper's model: 1200 factors of 32 x 32, 5 MB packed),
 * so halving them halves the time.
 *
 * Free run (free_run = true): a Gaussian belief over the lagged outputs, propagated by exact
 * moment matching over the hyperparameter mixture, as NarxPredictor.free_run_step: eqs. (1)-(6)
 * of gp_model/uncertain_input.py (MomentMatcher, _woodbury_terms) and its belief shift
 * (narx_belief_start, narx_belief_step). Every output's GP is expressed in output 0's input
 * frame (frame_gp), with the per-sample A_s = K_inv[s] = V_s^T V_s precomputed at load. A
 * lagged output that is a regressor takes its covariance with the prediction from eq. (2); one
 * that is not (output lags that skip a lag, e.g. (2,) or (1, 3)) takes the linear-Gaussian
 * projection of _cross_covariance_of_lagged_outputs, with numpy's hermitian pseudo-inverse
 * (pseudo_inverse). As MomentMatcher._standardise, every step first checks the regressor
 * covariance (covariance_problem): finite, symmetric and positive semi-definite to
 * COVARIANCE_TOLERANCE, or the step is refused. Both use one symmetric eigen-solver
 * (symmetric_eigen, cyclic Jacobi).
 */
#include <float.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gp_predict.h"
#include "model.h"
#include "model_config.h"

#define DATA_MAGIC "FGPNARX1"
#define SIGNALS (N_INPUTS + N_OUTPUTS)

/* Where the hidden state lives in the model's state array (model.h). */
#define INPUT_HISTORY 0                                /* MAX_LAG x N_INPUTS, row i: i steps ago */
#define OUTPUT_HISTORY (MAX_LAG * N_INPUTS)            /* MAX_LAG x N_OUTPUTS */
#define OUTSIDE_ENVELOPE (MAX_LAG * SIGNALS)           /* 1.0 while outside the envelope */
/* The free-run belief over y(k-1), ..., y(k-L), L = MAX_OUTPUT_LAG, lag-major: entry
   (lag - 1) * N_OUTPUTS + output (gp_model/uncertain_input.py, narx_belief_start). */
#define BELIEF_MEAN (OUTSIDE_ENVELOPE + 1)             /* BELIEF_SIZE */
#define BELIEF_COV (BELIEF_MEAN + BELIEF_SIZE)         /* BELIEF_SIZE x BELIEF_SIZE, row-major */
#define D N_REGRESSORS
#define KNOWN_REGRESSORS (N_INPUTS * N_INPUT_LAGS)     /* the exact part of the regressor */
#define N_Z (N_OUTPUTS * N_OUTPUT_LAGS)                /* lagged outputs that are regressors */

/* One output's GP (pointers into Model.data). */
typedef struct {
    int m, S, lower_triangular;
    size_t sample_size;                      /* doubles per hyperparameter sample */
    const double *input_mean, *input_scale;  /* (d,) */
    double output_mean, output_scale;
    const double *basis;                     /* (m, d) */
    const double *samples;                   /* S blocks of sample_size doubles */
    double *signal_variance;                 /* (S,) exp(log_signal_variance) */
    /* The GP in the common frame (output 0's input standardisation; frame_gp): */
    double *frame_basis;                     /* (m, d) X_a */
    double *precision;                       /* (S, d) diagonal of Lambda_a^-1 = 2 w / ratio^2 */
    double *K_inv;                           /* (S, m, m) A_s = V_s^T V_s */
    /* moment-matching scratch for the current sample s (eq. numbers of uncertain_input.py): */
    double *u;                               /* (m, d) u_ai = Lambda_a^-1 nu_ai */
    double *q;                               /* (m,) q_ai, eq. 1 */
    double *weighted;                        /* (m,) beta_ai q_ai */
    double M[D * D], log_det;                /* M_a and ln|I + T_a| (eq. 6) */
} OutputGP;

/* Scratch of _woodbury_terms (d x d each). */
typedef struct {
    double root[D], T[D * D], L[D * D], Y[D * D];
} WoodburyScratch;

struct Model {
    double *data;
    OutputGP gp[N_OUTPUTS];
    double *squared;                                  /* scratch (m_max, d) */
    double *k, *v;                                    /* scratch (m_max,) */
    /* free-run scratch */
    double *sample_means;                             /* (S, N_OUTPUTS) mixture components */
    double *u_M;                                      /* (m_max, d) */
    double *half_a, *half_b;                          /* (m_max,) */
    double frame_mean[D], frame_scale[D];             /* output 0's input standardisation */
    double M_ab[D * D], M_diff[D * D];
    WoodburyScratch woodbury;
    double next_state[MODEL_STATE_SIZE];              /* a step's result before its commit */
};

void model_free(Model *model) {
    if (model == NULL) return;
    for (int j = 0; j < N_OUTPUTS; j++) {
        OutputGP *gp = &model->gp[j];
        free(gp->signal_variance);
        free(gp->frame_basis);
        free(gp->precision);
        free(gp->K_inv);
        free(gp->u);
        free(gp->q);
        free(gp->weighted);
    }
    free(model->data);
    free(model->squared);
    free(model->k);
    free(model->v);
    free(model->sample_means);
    free(model->u_M);
    free(model->half_a);
    free(model->half_b);
    free(model);
}

static Model *fail(Model *model, char **error, char *message) {
    *error = message;
    model_free(model);
    return NULL;
}

/* The free run's constants and scratch (fmu_src/rate_predictor/predictor.py, _moment_matcher): every output's
 * GP in output 0's input frame, z_0 = (s_a z_a + mu_a - mu_0) / s_0 (frame_gp: basis * ratio +
 * offset, precision 2 w / ratio^2), and A_s = V_s^T V_s from the stored variance factors (by
 * columns, packed if lower triangular). Returns 0 if out of memory. */
static int prepare_free_run(Model *model, int m_max) {
    const OutputGP *lead = &model->gp[0];
    for (int c = 0; c < D; c++) {
        model->frame_mean[c] = lead->input_mean[c];
        model->frame_scale[c] = lead->input_scale[c];
    }
    double *dense = malloc(sizeof(double) * (size_t)m_max * (size_t)m_max); /* V_s, row-major */
    model->sample_means = malloc(sizeof(double) * (size_t)lead->S * N_OUTPUTS);
    model->u_M = malloc(sizeof(double) * (size_t)m_max * D);
    model->half_a = malloc(sizeof(double) * (size_t)m_max);
    model->half_b = malloc(sizeof(double) * (size_t)m_max);
    int ok = dense != NULL && model->sample_means != NULL && model->u_M != NULL && model->half_a != NULL
             && model->half_b != NULL;
    for (int j = 0; j < N_OUTPUTS && ok; j++) {
        OutputGP *gp = &model->gp[j];
        const size_t m = (size_t)gp->m, S = (size_t)gp->S;
        gp->frame_basis = malloc(sizeof(double) * m * D);
        gp->precision = malloc(sizeof(double) * S * D);
        gp->K_inv = malloc(sizeof(double) * S * m * m);
        gp->u = malloc(sizeof(double) * m * D);
        gp->q = malloc(sizeof(double) * m);
        gp->weighted = malloc(sizeof(double) * m);
        ok = gp->frame_basis != NULL && gp->precision != NULL && gp->K_inv != NULL && gp->u != NULL
             && gp->q != NULL && gp->weighted != NULL;
        if (!ok) break;
        double ratio[D], offset[D];
        for (int c = 0; c < D; c++) {
            ratio[c] = gp->input_scale[c] / model->frame_scale[c]; /* exactly 1 for output 0 */
            offset[c] = (gp->input_mean[c] - model->frame_mean[c]) / model->frame_scale[c];
        }
        for (size_t i = 0; i < m; i++)
            for (int c = 0; c < D; c++) gp->frame_basis[i * D + c] = gp->basis[i * D + c] * ratio[c] + offset[c];
        for (size_t s = 0; s < S; s++) {
            const double *sample = gp->samples + s * gp->sample_size;
            const double *kernel_weights = sample + m, *factor = sample + m + D + 2;
            for (int c = 0; c < D; c++) gp->precision[s * D + c] = 2.0 * kernel_weights[c] / (ratio[c] * ratio[c]);
            /* unpack V_s (stored by columns) into dense[row * m + column] */
            for (size_t column = 0; column < m; column++)
                for (size_t row = 0; row < m; row++) {
                    int stored = !gp->lower_triangular || row >= column;
                    dense[row * m + column] = stored ? *factor++ : 0.0;
                }
            /* A_s[i][k] = sum_r V_s[r][i] V_s[r][k] (frame_gp: einsum "sji,sjk->sik") */
            double *A = gp->K_inv + s * m * m;
            for (size_t i = 0; i < m; i++)
                for (size_t k = i; k < m; k++) {
                    double sum = 0.0;
                    for (size_t r = 0; r < m; r++) sum += dense[r * m + i] * dense[r * m + k];
                    A[i * m + k] = A[k * m + i] = sum;
                }
        }
    }
    free(dense);
    return ok;
}

Model *model_load(const char *resources_dir, char **error) {
    Model *model = calloc(1, sizeof(Model));
    if (model == NULL) return fail(NULL, error, NULL);
    model->data = read_model_data(resources_dir, DATA_MAGIC, DATA_DOUBLES, error);
    if (model->data == NULL) return fail(model, error, *error);
    /* Point every output's GP into the data (layout above). */
    const double *p = model->data;
    int m_max = 1;
    for (int j = 0; j < N_OUTPUTS; j++) {
        OutputGP *gp = &model->gp[j];
        gp->m = BASIS_POINTS[j];
        gp->S = HYPERPARAMETER_SAMPLES[j];
        gp->lower_triangular = LOWER_TRIANGULAR[j];
        size_t m = (size_t)gp->m;
        gp->sample_size = m + N_REGRESSORS + 2 + gp_factor_size(gp->m, gp->lower_triangular);
        gp->input_mean = p, p += N_REGRESSORS;
        gp->input_scale = p, p += N_REGRESSORS;
        gp->output_mean = *p++;
        gp->output_scale = *p++;
        gp->basis = p, p += (size_t)gp->m * N_REGRESSORS;
        gp->samples = p, p += (size_t)gp->S * gp->sample_size;
        gp->signal_variance = malloc(sizeof(double) * (size_t)gp->S);
        if (gp->signal_variance == NULL) return fail(model, error, NULL);
        for (int s = 0; s < gp->S; s++)
            gp->signal_variance[s] = exp(gp->samples[(size_t)s * gp->sample_size + m + N_REGRESSORS]);
        if (gp->m > m_max) m_max = gp->m;
    }
    model->squared = malloc(sizeof(double) * (size_t)m_max * N_REGRESSORS);
    model->k = malloc(sizeof(double) * (size_t)m_max);
    model->v = malloc(sizeof(double) * (size_t)m_max);
    if (model->squared == NULL || model->k == NULL || model->v == NULL) return fail(model, error, NULL);
    if (!prepare_free_run(model, m_max)) return fail(model, error, NULL);
    return model;
}

/* Mean and variance (measurement noise included) of output gp at regressor x (physical
 * units): the mixture over its hyperparameter samples (predictor.py, _Block.predict), each
 * sample's mean and latent variance by gp_predict.c. */
static void predict_output(const Model *model, const OutputGP *gp, const double x[N_REGRESSORS],
                           double *mean_out, double *var_out) {
    const int m = gp->m, d = N_REGRESSORS;
    double xs[N_REGRESSORS];
    gp_standardise(d, x, gp->input_mean, gp->input_scale, xs);
    gp_squared_distances(m, d, xs, gp->basis, model->squared);
    double sum_mean = 0.0, sum_second = 0.0;
    for (int s = 0; s < gp->S; s++) {
        const double *sample = gp->samples + (size_t)s * gp->sample_size;
        const double *weights = sample, *kernel_weights = sample + m;
        const double log_signal_variance = sample[m + d], noise_variance = sample[m + d + 1];
        const double *factor = sample + m + d + 2;
        gp_kernel_row(m, d, model->squared, kernel_weights, log_signal_variance, model->k);
        const double mu = gp_mean(m, model->k, weights, 1);
        const double variance = gp_latent_variance(m, factor, gp->lower_triangular, model->k,
                                                   gp->signal_variance[s], model->v) + noise_variance;
        sum_mean += mu;
        sum_second += variance + mu * mu;
    }
    const double mean = sum_mean / gp->S;
    *mean_out = mean * gp->output_scale + gp->output_mean;
    *var_out = gp_spread(sum_second / gp->S, mean) * gp->output_scale * gp->output_scale;
}

/* -- free run: moment matching (gp_model/uncertain_input.py) ----------------------------- */

/* _woodbury_terms: M(P) = (P + S^-1)^-1 = P^-1/2 (I + T)^-1 T P^-1/2 with T = P^1/2 S P^1/2,
 * and ln|I + T| (eq. 6), for a positive diagonal precision P (d,) and the standardised input
 * covariance S (d x d, symmetric positive semi-definite, may be singular). I + T has all
 * eigenvalues >= 1, so its Cholesky factor exists; returns 0 if it does not (S is then far from
 * positive semi-definite: a bug, refused as a step). M is symmetrised as there. */
static int woodbury_terms(WoodburyScratch *w, const double precision[D], const double S[D * D],
                          double M[D * D], double *log_det) {
    double *root = w->root, *T = w->T, *L = w->L, *Y = w->Y;
    for (int i = 0; i < D; i++) root[i] = sqrt(precision[i]);
    for (int i = 0; i < D; i++)
        for (int j = 0; j < D; j++) T[i * D + j] = S[i * D + j] * (root[i] * root[j]);
    /* L L^T = I + T (Cholesky, lower) */
    double sum_log = 0.0;
    for (int j = 0; j < D; j++) {
        double pivot = 1.0 + T[j * D + j];
        for (int k = 0; k < j; k++) pivot -= L[j * D + k] * L[j * D + k];
        if (!(pivot > 0.0)) return 0;
        L[j * D + j] = sqrt(pivot);
        sum_log += log(L[j * D + j]);
        for (int i = j + 1; i < D; i++) {
            double value = T[i * D + j];
            for (int k = 0; k < j; k++) value -= L[i * D + k] * L[j * D + k];
            L[i * D + j] = value / L[j * D + j];
        }
        for (int i = 0; i < j; i++) L[i * D + j] = 0.0;
    }
    /* Y = L^-1 T (forward substitution), then M P^1/2..P^1/2 = L^-T Y (back substitution), in M */
    for (int c = 0; c < D; c++) {
        for (int i = 0; i < D; i++) {
            double value = T[i * D + c];
            for (int k = 0; k < i; k++) value -= L[i * D + k] * Y[k * D + c];
            Y[i * D + c] = value / L[i * D + i];
        }
        for (int i = D - 1; i >= 0; i--) {
            double value = Y[i * D + c];
            for (int k = i + 1; k < D; k++) value -= L[k * D + i] * M[k * D + c];
            M[i * D + c] = value / L[i * D + i];
        }
    }
    for (int i = 0; i < D; i++)
        for (int j = 0; j < D; j++) M[i * D + j] /= root[i] * root[j];
    for (int i = 0; i < D; i++)
        for (int j = i + 1; j < D; j++) M[i * D + j] = M[j * D + i] = 0.5 * (M[i * D + j] + M[j * D + i]);
    *log_det = 2.0 * sum_log;
    return 1;
}

/* u^T M u for u (d,) and a symmetric M (d x d). */
static double quadratic_form(const double u[D], const double M[D * D]) {
    double total = 0.0;
    for (int i = 0; i < D; i++) {
        double row = 0.0;
        for (int j = 0; j < D; j++) row += M[i * D + j] * u[j];
        total += row * u[i];
    }
    return total;
}

/* -- symmetric eigen-decomposition, for the covariance check and the pseudo-inverse --------- */

/* gp_model/uncertain_input.py: COVARIANCE_TOLERANCE (relative asymmetry and negative
 * eigenvalues tolerated in the standardised input covariance) and the rcond of the pinv in
 * _cross_covariance_of_lagged_outputs. */
#define COVARIANCE_TOLERANCE 1e-10
#define PINV_RCOND 1e-10
/* Jacobi stops when off(A) <= JACOBI_TOLERANCE ||A||_F (Golub & Van Loan's tol; the eigenvalues
 * are then exact to about eps ||A||_F, as LAPACK's); quadratic convergence takes a handful of
 * sweeps, the cap only guards against a pathological input. */
#define JACOBI_TOLERANCE DBL_EPSILON
#define JACOBI_MAX_SWEEPS 100

/* Eigenvalues (values, n) and, if vectors is not NULL, orthonormal eigenvectors (the columns of
 * vectors, n x n row-major) of the symmetric n x n matrix A (row-major, n <= D; overwritten: it
 * ends diagonal) by the cyclic Jacobi method (Golub & Van Loan, Matrix Computations, 4th ed.,
 * sec. 8.5: symSchur2 and the cyclic-by-row algorithm). Each rotation J(p, q, theta), with
 * J_pp = J_qq = c, J_pq = s, J_qp = -s, is chosen so that (J^T A J)_pq = 0:
 *   tau = (a_qq - a_pp) / (2 a_pq),  t = sign(tau) / (|tau| + sqrt(1 + tau^2)) (the smaller
 *   root of t^2 + 2 tau t - 1 = 0, so |theta| <= pi/4),  c = 1 / sqrt(1 + t^2),  s = t c;
 * A <- J^T A J and V <- V J, sweeping the pairs (p, q) row by row until off(A) is negligible. */
static void symmetric_eigen(int n, double *A, double *values, double *vectors) {
    double norm2 = 0.0; /* ||A||_F^2, invariant under the rotations */
    for (int i = 0; i < n * n; i++) norm2 += A[i] * A[i];
    if (vectors != NULL)
        for (int i = 0; i < n; i++)
            for (int j = 0; j < n; j++) vectors[i * n + j] = i == j ? 1.0 : 0.0;
    for (int sweep = 0; sweep < JACOBI_MAX_SWEEPS; sweep++) {
        double off2 = 0.0; /* off(A)^2 */
        for (int p = 0; p < n; p++)
            for (int q = p + 1; q < n; q++) off2 += 2.0 * A[p * n + q] * A[p * n + q];
        if (!(off2 > JACOBI_TOLERANCE * JACOBI_TOLERANCE * norm2)) break; /* NaN stops too */
        for (int p = 0; p < n - 1; p++)
            for (int q = p + 1; q < n; q++) {
                const double a_pq = A[p * n + q];
                if (a_pq == 0.0) continue;
                const double tau = (A[q * n + q] - A[p * n + p]) / (2.0 * a_pq);
                const double t = (tau >= 0.0 ? 1.0 : -1.0) / (fabs(tau) + hypot(1.0, tau));
                const double c = 1.0 / sqrt(1.0 + t * t), s = t * c;
                for (int k = 0; k < n; k++) { /* A J: columns p and q */
                    const double a_kp = A[k * n + p], a_kq = A[k * n + q];
                    A[k * n + p] = c * a_kp - s * a_kq;
                    A[k * n + q] = s * a_kp + c * a_kq;
                }
                for (int k = 0; k < n; k++) { /* J^T (A J): rows p and q */
                    const double a_pk = A[p * n + k], a_qk = A[q * n + k];
                    A[p * n + k] = c * a_pk - s * a_qk;
                    A[q * n + k] = s * a_pk + c * a_qk;
                }
                A[p * n + q] = A[q * n + p] = 0.0; /* zero in exact arithmetic: drop the rounding */
                if (vectors != NULL)
                    for (int k = 0; k < n; k++) {
                        const double v_kp = vectors[k * n + p], v_kq = vectors[k * n + q];
                        vectors[k * n + p] = c * v_kp - s * v_kq;
                        vectors[k * n + q] = s * v_kp + c * v_kq;
                    }
            }
    }
    for (int i = 0; i < n; i++) values[i] = A[i * n + i];
}

/* numpy.linalg.pinv(A, rcond, hermitian=True) of a symmetric n x n A (row-major, n <= D) into
 * P: A = V diag(lambda) V^T (symmetric_eigen), P = sum over the eigenpairs with
 * |lambda_k| > rcond max_k |lambda_k| of v_k v_k^T / lambda_k (the others, and all of a zero A,
 * are dropped, as numpy's cutoff does). */
static void pseudo_inverse(int n, const double *A, double rcond, double *P) {
    double work[D * D], vectors[D * D], values[D], largest = 0.0;
    for (int i = 0; i < n * n; i++) work[i] = A[i];
    symmetric_eigen(n, work, values, vectors);
    for (int k = 0; k < n; k++)
        if (fabs(values[k]) > largest) largest = fabs(values[k]);
    for (int i = 0; i < n * n; i++) P[i] = 0.0;
    for (int k = 0; k < n; k++) {
        if (!(fabs(values[k]) > rcond * largest)) continue;
        for (int i = 0; i < n; i++) {
            const double scaled = vectors[i * n + k] / values[k];
            for (int j = 0; j < n; j++) P[i * n + j] += scaled * vectors[j * n + k];
        }
    }
}

/* MomentMatcher._standardise: S = x_cov standardised by the frame's scales (frame 0) and
 * symmetrised, after the checks there: x_mean and x_cov finite; max |S - S^T| <=
 * COVARIANCE_TOLERANCE max |S|; smallest eigenvalue of S >= -COVARIANCE_TOLERANCE max(largest,
 * 0). Judged in the standardised frame, so that regressors in different units weigh alike.
 * Returns NULL, or a malloc'd message saying what is wrong (also NULL if out of memory, with
 * *failed set: the caller must not go on). */
static char *covariance_problem(const Model *model, const double x_mean[D], const double x_cov[D * D],
                                double S[D * D], int *failed) {
    *failed = 1;
    for (int i = 0; i < D; i++) {
        if (!isfinite(x_mean[i])) return format_message("the free-run regressor mean contains NaN or inf");
        for (int j = 0; j < D; j++)
            if (!isfinite(x_cov[i * D + j]))
                return format_message("the free-run regressor covariance contains NaN or inf");
    }
    double size = 0.0, asymmetry = 0.0;
    for (int i = 0; i < D; i++)
        for (int j = 0; j < D; j++) S[i * D + j] = x_cov[i * D + j] / (model->frame_scale[i] * model->frame_scale[j]);
    for (int i = 0; i < D; i++)
        for (int j = 0; j < D; j++) {
            size = fmax(size, fabs(S[i * D + j]));
            asymmetry = fmax(asymmetry, fabs(S[i * D + j] - S[j * D + i]));
        }
    if (asymmetry > COVARIANCE_TOLERANCE * size)
        return format_message("the free-run regressor covariance is not symmetric: max |S - S^T| = %.3g against "
                              "max |S| = %.3g (S = the covariance standardised by the GP input scales; tolerance "
                              "%.3g relative, COVARIANCE_TOLERANCE of gp_model/uncertain_input.py)",
                              asymmetry, size, COVARIANCE_TOLERANCE);
    double work[D * D], values[D];
    for (int i = 0; i < D; i++)
        for (int j = i + 1; j < D; j++) S[i * D + j] = S[j * D + i] = 0.5 * (S[i * D + j] + S[j * D + i]);
    for (int i = 0; i < D * D; i++) work[i] = S[i];
    symmetric_eigen(D, work, values, NULL);
    double smallest = values[0], largest = values[0];
    for (int i = 1; i < D; i++) smallest = fmin(smallest, values[i]), largest = fmax(largest, values[i]);
    if (smallest < -COVARIANCE_TOLERANCE * fmax(largest, 0.0))
        return format_message("the free-run regressor covariance is not positive semi-definite: the standardised "
                              "covariance has eigenvalue %.3g (largest %.3g; tolerance %.3g relative, "
                              "COVARIANCE_TOLERANCE of gp_model/uncertain_input.py)",
                              smallest, largest, COVARIANCE_TOLERANCE);
    *failed = 0;
    return NULL;
}

/* The message of a failed Cholesky factor of I + T (eq. 6): not expected once S passed
 * covariance_problem, so a bug. */
static char *cholesky_failure(void) {
    return format_message("the free-run input covariance is not positive semi-definite (a Cholesky factor of "
                          "I + T, eq. 6 of gp_model/uncertain_input.py, failed); please report");
}

/* Eqs. 1 and 2 of sample s, every output a (MomentMatcher.__call__, singles, mean_s, cross_s): u_ai,
 * M_a, ln|I + T_a| and q_a (eq. 1 in the Woodbury form -1/2 nu^T (S + Lambda)^-1 nu =
 * -1/2 nu^T u + 1/2 u^T M_a u), kept in the OutputGP scratch for sample_pair_covariance;
 * E[f_a] = beta_a^T q_a (eq. 1) into model->sample_means in raw units; Cov[x, f_a] =
 * M_a sum_i u_ai beta_ai q_ai (eq. 2 with S (S + Lambda_a)^-1 nu_i = M_a u_i) added to
 * cross_sum (standardised input, standardised output). m: the standardised input mean, S its
 * covariance. Returns 0 if a Cholesky factor of eq. 6 fails. */
static int sample_means_and_cross_covariances(Model *model, int s, const double m[D], const double S[D * D],
                                              double cross_sum[D * N_OUTPUTS]) {
    for (int a = 0; a < N_OUTPUTS; a++) {
        OutputGP *gp = &model->gp[a];
        const double *sample = gp->samples + (size_t)s * gp->sample_size;
        const double *precision = gp->precision + (size_t)s * D;
        const double *beta = sample, log_signal_variance = sample[gp->m + D];
        if (!woodbury_terms(&model->woodbury, precision, S, gp->M, &gp->log_det)) return 0;
        double mean = 0.0, sum_u[D] = {0.0};
        for (int i = 0; i < gp->m; i++) {
            double *u = gp->u + (size_t)i * D, nu_u = 0.0;
            for (int c = 0; c < D; c++) {
                double nu = gp->frame_basis[(size_t)i * D + c] - m[c];
                u[c] = nu * precision[c];
                nu_u += nu * u[c];
            }
            gp->q[i] = exp(log_signal_variance - 0.5 * gp->log_det - 0.5 * nu_u + 0.5 * quadratic_form(u, gp->M));
            gp->weighted[i] = beta[i] * gp->q[i];
            mean += gp->weighted[i];
            for (int c = 0; c < D; c++) sum_u[c] += u[c] * gp->weighted[i];
        }
        model->sample_means[(size_t)s * N_OUTPUTS + a] = gp->output_mean + gp->output_scale * mean;
        for (int c = 0; c < D; c++) {
            double value = 0.0;
            for (int e = 0; e < D; e++) value += gp->M[c * D + e] * sum_u[e];
            cross_sum[c * N_OUTPUTS + a] += value;
        }
    }
    return 1;
}

/* Eqs. 3-6 of sample s for the outputs a <= b (MomentMatcher.__call__, cov_s), from the scratch of
 * sample_means_and_cross_covariances: Cov[f_a, f_b] = beta_a^T (Q^ab - q_a q_b^T) beta_b with
 * Q^ab_ij - q_ai q_bj = q_ai q_bj expm1(D_ij) (eq. 6), z^T M_ab z expanded over z_ij = u_ai + u_bj;
 * for a == b plus the expected variance (eq. 4, clipped at zero as GaussianProcess.predict) and
 * the noise (eq. 5). Standardised output units. Returns 0 if a Cholesky factor of eq. 6 fails. */
static int sample_pair_covariance(Model *model, int s, int a, int b, const double S[D * D], double *covariance) {
    const OutputGP *ga = &model->gp[a], *gb = &model->gp[b];
    const double *precision_a = ga->precision + (size_t)s * D, *precision_b = gb->precision + (size_t)s * D;
    double precision_ab[D], log_det_ab;
    for (int c = 0; c < D; c++) precision_ab[c] = precision_a[c] + precision_b[c];
    if (!woodbury_terms(&model->woodbury, precision_ab, S, model->M_ab, &log_det_ab)) return 0;
    const double constant = -0.5 * (log_det_ab - ga->log_det - gb->log_det);
    /* half_a_i = 1/2 u_ai^T (M_ab - M_a) u_ai + the constant; half_b_j likewise; u_M = u_a M_ab */
    for (int c = 0; c < D * D; c++) model->M_diff[c] = model->M_ab[c] - ga->M[c];
    for (int i = 0; i < ga->m; i++) {
        const double *u = ga->u + (size_t)i * D;
        model->half_a[i] = 0.5 * quadratic_form(u, model->M_diff) + constant;
        for (int c = 0; c < D; c++) {
            double value = 0.0;
            for (int e = 0; e < D; e++) value += u[e] * model->M_ab[e * D + c];
            model->u_M[(size_t)i * D + c] = value;
        }
    }
    for (int c = 0; c < D * D; c++) model->M_diff[c] = model->M_ab[c] - gb->M[c];
    for (int j = 0; j < gb->m; j++) model->half_b[j] = 0.5 * quadratic_form(gb->u + (size_t)j * D, model->M_diff);
    const double *K_inv = ga->K_inv + (size_t)s * ga->m * ga->m;
    double sum = 0.0, trace = 0.0; /* trace: tr(K_inv Q^aa) (eq. 4), a == b only */
    for (int i = 0; i < ga->m; i++) {
        const double *u_M = model->u_M + (size_t)i * D;
        double row = 0.0, row_trace = 0.0;
        for (int j = 0; j < gb->m; j++) {
            const double *u_b = gb->u + (size_t)j * D;
            double exponent = model->half_a[i] + model->half_b[j];
            for (int c = 0; c < D; c++) exponent += u_M[c] * u_b[c];
            double excess = expm1(exponent);
            row += excess * gb->weighted[j];
            if (a == b) row_trace += K_inv[(size_t)i * ga->m + j] * (ga->q[j] * (1.0 + excess));
        }
        sum += ga->weighted[i] * row;
        trace += ga->q[i] * row_trace;
    }
    if (a == b) {
        const double *sample = ga->samples + (size_t)s * ga->sample_size;
        double expected_var = ga->signal_variance[s] - trace;
        sum += (expected_var > 0.0 ? expected_var : 0.0) + sample[ga->m + D + 1];
    }
    *covariance = sum;
    return 1;
}

/* The mixture over the n_samples models (MomentMatcher class docstring), centred so that S = 1
 * adds exact zeros: E[f] = E_s[m_s], Cov[f] = E_s[C_s] + Cov_s[m_s], Cov[x, f] = E_s[Cov_s[x, f]],
 * in raw units, from the per-sample means (model->sample_means) and the sums over the samples of
 * the covariances (cov_sum) and cross-covariances (cross_sum) in standardised units. */
static void mixture_moments(const Model *model, int n_samples, const double cov_sum[N_OUTPUTS * N_OUTPUTS],
                            const double cross_sum[D * N_OUTPUTS], double out_mean[N_OUTPUTS],
                            double out_cov[N_OUTPUTS * N_OUTPUTS], double cross_cov[D * N_OUTPUTS]) {
    for (int a = 0; a < N_OUTPUTS; a++) {
        double total = 0.0;
        for (int s = 0; s < n_samples; s++) total += model->sample_means[(size_t)s * N_OUTPUTS + a];
        out_mean[a] = total / n_samples;
    }
    for (int a = 0; a < N_OUTPUTS; a++)
        for (int b = 0; b < N_OUTPUTS; b++) {
            double spread = 0.0;
            for (int s = 0; s < n_samples; s++)
                spread += (model->sample_means[(size_t)s * N_OUTPUTS + a] - out_mean[a])
                          * (model->sample_means[(size_t)s * N_OUTPUTS + b] - out_mean[b]);
            out_cov[a * N_OUTPUTS + b] = cov_sum[a * N_OUTPUTS + b] / n_samples
                                         * (model->gp[a].output_scale * model->gp[b].output_scale)
                                         + spread / n_samples;
        }
    for (int c = 0; c < D; c++)
        for (int a = 0; a < N_OUTPUTS; a++)
            cross_cov[c * N_OUTPUTS + a] = cross_sum[c * N_OUTPUTS + a] / n_samples * model->frame_scale[c]
                                           * model->gp[a].output_scale;
}

/* MomentMatcher.__call__ with include_noise = True: the exact mean (N_OUTPUTS), covariance
 * (N_OUTPUTS x N_OUTPUTS, row-major) and input-output cross-covariance (d x N_OUTPUTS) of the
 * mixture over the S hyperparameter samples (sample s of every output forms model s) at a
 * regressor x ~ N(x_mean, x_cov) (raw units): the input standardised and checked
 * (covariance_problem), then per sample eqs. 1-2 (sample_means_and_cross_covariances) and
 * eqs. 3-6 (sample_pair_covariance), then the mixture (mixture_moments). Returns 0 and sets
 * *problem (a malloc'd message; NULL if out of memory) if x_cov fails the checks of
 * covariance_problem or a Cholesky factor of eq. 6 fails. */
static int moment_match(Model *model, const double x_mean[D], const double x_cov[D * D], double out_mean[N_OUTPUTS],
                        double out_cov[N_OUTPUTS * N_OUTPUTS], double cross_cov[D * N_OUTPUTS], char **problem) {
    double m[D], S[D * D];
    int failed;
    /* MomentMatcher._standardise: into the common frame, checked, S symmetrised */
    *problem = covariance_problem(model, x_mean, x_cov, S, &failed);
    if (failed) return 0;
    for (int i = 0; i < D; i++) m[i] = (x_mean[i] - model->frame_mean[i]) / model->frame_scale[i];
    const int n_samples = model->gp[0].S;
    double cov_sum[N_OUTPUTS * N_OUTPUTS] = {0.0}, cross_sum[D * N_OUTPUTS] = {0.0};
    for (int s = 0; s < n_samples; s++) {
        if (!sample_means_and_cross_covariances(model, s, m, S, cross_sum)) {
            *problem = cholesky_failure();
            return 0;
        }
        for (int a = 0; a < N_OUTPUTS; a++)
            for (int b = a; b < N_OUTPUTS; b++) {
                double covariance;
                if (!sample_pair_covariance(model, s, a, b, S, &covariance)) {
                    *problem = cholesky_failure();
                    return 0;
                }
                cov_sum[a * N_OUTPUTS + b] += covariance;
                if (b != a) cov_sum[b * N_OUTPUTS + a] += covariance;
            }
    }
    mixture_moments(model, n_samples, cov_sum, cross_sum, out_mean, out_cov, cross_cov);
    return 1;
}

/* narx_belief_step (include_noise = True): predict y(k) from the belief over y(k-1), ..., y(k-L)
 * in state (BELIEF_MEAN, BELIEF_COV) and the exact known regressors x_known, and write the
 * shifted belief over y(k), ..., y(k-L+1) into next. Returns 0 and sets *problem (as
 * moment_match) if moment_match fails. */
static int belief_step(Model *model, const double *state, const double *x_known,
                       double y_mean[N_OUTPUTS], double y_var[N_OUTPUTS], double *next, char **problem) {
    const double *mean = state + BELIEF_MEAN, *cov = state + BELIEF_COV;
    int z_rows[N_Z]; /* regressor n_u + i is belief entry z_rows[i] */
    double x_mean[D], x_cov[D * D] = {0.0}, y_cov[N_OUTPUTS * N_OUTPUTS], cross[D * N_OUTPUTS];
    for (int c = 0; c < N_OUTPUTS; c++)
        for (int i = 0; i < N_OUTPUT_LAGS; i++) z_rows[c * N_OUTPUT_LAGS + i] = (OUTPUT_LAGS[i] - 1) * N_OUTPUTS + c;
    for (int i = 0; i < KNOWN_REGRESSORS; i++) x_mean[i] = x_known[i];
    for (int i = 0; i < N_Z; i++) {
        x_mean[KNOWN_REGRESSORS + i] = mean[z_rows[i]];
        for (int j = 0; j < N_Z; j++)
            x_cov[(KNOWN_REGRESSORS + i) * D + KNOWN_REGRESSORS + j] = cov[z_rows[i] * BELIEF_SIZE + z_rows[j]];
    }
    if (!moment_match(model, x_mean, x_cov, y_mean, y_cov, cross, problem)) return 0;
    /* Cov(z, y) (_cross_covariance_of_lagged_outputs): a belief row z_rows[i] is regressor
       n_u + i, whose cross-covariance eq. 2 gives exactly; the other rows (lags the structure
       skips: N_Z < BELIEF_SIZE) get the linear-Gaussian projection Cov(z, x_z) Cov(x_z)^+ Cov(x_z, y)
       (Deisenroth 2010, sec. 2.3.2), Cov(x_z)^+ as numpy.linalg.pinv(rcond = 1e-10, hermitian)
       and the products in numpy's order, (Cov(z, x_z) Cov(x_z)^+) Cov(x_z, y). */
    double cov_z_y[BELIEF_SIZE * N_OUTPUTS];
    if (N_Z < BELIEF_SIZE) { /* a constant: compiled away without skipped lags */
        double x_z_cov[D * D], pinv[D * D]; /* N_Z x N_Z */
        for (int i = 0; i < N_Z; i++)
            for (int j = 0; j < N_Z; j++) x_z_cov[i * N_Z + j] = cov[z_rows[i] * BELIEF_SIZE + z_rows[j]];
        pseudo_inverse(N_Z, x_z_cov, PINV_RCOND, pinv);
        for (int row = 0; row < BELIEF_SIZE; row++) {
            double left[D]; /* row of Cov(z, x_z) Cov(x_z)^+ */
            for (int j = 0; j < N_Z; j++) {
                double value = 0.0;
                for (int i = 0; i < N_Z; i++) value += cov[row * BELIEF_SIZE + z_rows[i]] * pinv[i * N_Z + j];
                left[j] = value;
            }
            for (int a = 0; a < N_OUTPUTS; a++) {
                double value = 0.0;
                for (int j = 0; j < N_Z; j++) value += left[j] * cross[(KNOWN_REGRESSORS + j) * N_OUTPUTS + a];
                cov_z_y[row * N_OUTPUTS + a] = value;
            }
        }
    }
    for (int i = 0; i < N_Z; i++)
        for (int a = 0; a < N_OUTPUTS; a++)
            cov_z_y[z_rows[i] * N_OUTPUTS + a] = cross[(KNOWN_REGRESSORS + i) * N_OUTPUTS + a];
    /* The shifted belief: [y(k); the first (L - 1) n outputs of the old], joint covariance, symmetrised. */
    const int keep = BELIEF_SIZE - N_OUTPUTS;
    double *new_mean = next + BELIEF_MEAN, *new_cov = next + BELIEF_COV;
    for (int a = 0; a < N_OUTPUTS; a++) new_mean[a] = y_mean[a], y_var[a] = y_cov[a * N_OUTPUTS + a];
    for (int i = 0; i < keep; i++) new_mean[N_OUTPUTS + i] = mean[i];
    for (int i = 0; i < BELIEF_SIZE; i++)
        for (int j = 0; j < BELIEF_SIZE; j++) {
            double value;
            if (i < N_OUTPUTS && j < N_OUTPUTS) value = y_cov[i * N_OUTPUTS + j];
            else if (i < N_OUTPUTS) value = cov_z_y[(j - N_OUTPUTS) * N_OUTPUTS + i];
            else if (j < N_OUTPUTS) value = cov_z_y[(i - N_OUTPUTS) * N_OUTPUTS + j];
            else value = cov[(i - N_OUTPUTS) * BELIEF_SIZE + (j - N_OUTPUTS)];
            new_cov[i * BELIEF_SIZE + j] = value;
        }
    for (int i = 0; i < BELIEF_SIZE; i++)
        for (int j = i + 1; j < BELIEF_SIZE; j++)
            new_cov[i * BELIEF_SIZE + j] = new_cov[j * BELIEF_SIZE + i]
                = 0.5 * (new_cov[i * BELIEF_SIZE + j] + new_cov[j * BELIEF_SIZE + i]);
    return 1;
}

/* z with P(|N(0, 1)| <= z) = level: the normal quantile of 0.5 + level / 2 by Wichura's
 * algorithm AS241 (Applied Statistics 37, 1988, 477-484), as Python's statistics.NormalDist. */
static double two_sided_quantile(double level) {
    double p = 0.5 + 0.5 * level, q = p - 0.5, r, num, den;
    if (fabs(q) <= 0.425) {
        r = 0.180625 - q * q;
        num = (((((((2.5090809287301226727e+3 * r + 3.3430575583588128105e+4) * r + 6.7265770927008700853e+4) * r
                   + 4.5921953931549871457e+4) * r + 1.3731693765509461125e+4) * r + 1.9715909503065514427e+3) * r
                + 1.3314166789178437745e+2) * r + 3.3871328727963666080e+0) * q;
        den = (((((((5.2264952788528545610e+3 * r + 2.8729085735721942674e+4) * r + 3.9307895800092710610e+4) * r
                   + 2.1213794301586595867e+4) * r + 5.3941960214247511077e+3) * r + 6.8718700749205790830e+2) * r
                + 4.2313330701600911252e+1) * r + 1.0);
        return num / den;
    }
    r = q <= 0.0 ? p : 1.0 - p;
    r = sqrt(-log(r));
    if (r <= 5.0) {
        r = r - 1.6;
        num = (((((((7.74545014278341407640e-4 * r + 2.27238449892691845833e-2) * r + 2.41780725177450611770e-1) * r
                   + 1.27045825245236838258e+0) * r + 3.64784832476320460504e+0) * r + 5.76949722146069140550e+0) * r
                + 4.63033784615654529590e+0) * r + 1.42343711074968357734e+0);
        den = (((((((1.05075007164441684324e-9 * r + 5.47593808499534494600e-4) * r + 1.51986665636164571966e-2) * r
                   + 1.48103976427480074590e-1) * r + 6.89767334985100004550e-1) * r + 1.67638483018380384940e+0) * r
                + 2.05319162663775882187e+0) * r + 1.0);
    } else {
        r = r - 5.0;
        num = (((((((2.01033439929228813265e-7 * r + 2.71155556874348757815e-5) * r + 1.24266094738807843860e-3) * r
                   + 2.65321895265761230930e-2) * r + 2.96560571828504891230e-1) * r + 1.78482653991729133580e+0) * r
                + 5.46378491116411436990e+0) * r + 6.65790464350110377720e+0);
        den = (((((((2.04426310338993978564e-15 * r + 1.42151175831644588870e-7) * r + 1.84631831751005468180e-5) * r
                   + 7.86869131145613259100e-4) * r + 1.48753612908506148525e-2) * r + 1.36929880922735805310e-1) * r
                + 5.99832206555887937690e-1) * r + 1.0);
    }
    double x = num / den;
    return q < 0.0 ? -x : x;
}

/* Outputs mean -/+ z sd (RatePredictor._set_outputs). */
static void set_outputs(double *values, const double mean[N_OUTPUTS], const double var[N_OUTPUTS]) {
    double z = two_sided_quantile(values[CONFIDENCE_LEVEL_VR]);
    for (int j = 0; j < N_OUTPUTS; j++) {
        double half_width = z * sqrt(var[j]);
        values[MEAN_VR[j]] = mean[j];
        values[LOWER_VR[j]] = mean[j] - half_width;
        values[UPPER_VR[j]] = mean[j] + half_width;
    }
}

void model_start(Model *model, double *values, double *state) {
    (void)model;
    double y0[N_OUTPUTS], zero[N_OUTPUTS];
    /* Before t0 the vehicle is steady: every lag holds the values set at initialisation. */
    for (int lag = 0; lag < MAX_LAG; lag++) {
        for (int c = 0; c < N_INPUTS; c++) state[INPUT_HISTORY + lag * N_INPUTS + c] = values[CONTROL_VR[c]];
        for (int c = 0; c < N_OUTPUTS; c++) state[OUTPUT_HISTORY + lag * N_OUTPUTS + c] = values[PREVIOUS_VR[c]];
    }
    state[OUTSIDE_ENVELOPE] = 0.0;
    for (int j = 0; j < N_OUTPUTS; j++) y0[j] = values[PREVIOUS_VR[j]], zero[j] = 0.0;
    /* The free-run belief (narx_belief_start, NarxPredictor.free_run_start): the given outputs
       at every lag, known exactly (zero covariance); unused in one-step mode. */
    for (int i = 0; i < BELIEF_SIZE; i++) state[BELIEF_MEAN + i] = y0[i % N_OUTPUTS];
    for (int i = 0; i < BELIEF_SIZE * BELIEF_SIZE; i++) state[BELIEF_COV + i] = 0.0;
    set_outputs(values, y0, zero);
}

char *model_advance(Model *model, const Slave *slave, double *values, double *state, double t, double h) {
    double *next = model->next_state; /* the new state, committed at the end */
    double *inputs = next + INPUT_HISTORY, *outputs = next + OUTPUT_HISTORY;
    const int free_run = values[FREE_RUN_VR] != 0.0;
    /* Push the current sample (row 0) into both histories; free run feeds back the means. */
    for (int lag = MAX_LAG - 1; lag > 0; lag--) {
        for (int c = 0; c < N_INPUTS; c++) inputs[lag * N_INPUTS + c] = state[INPUT_HISTORY + (lag - 1) * N_INPUTS + c];
        for (int c = 0; c < N_OUTPUTS; c++)
            outputs[lag * N_OUTPUTS + c] = state[OUTPUT_HISTORY + (lag - 1) * N_OUTPUTS + c];
    }
    for (int c = 0; c < N_INPUTS; c++) inputs[c] = values[CONTROL_VR[c]];
    for (int c = 0; c < N_OUTPUTS; c++) outputs[c] = values[free_run ? MEAN_VR[c] : PREVIOUS_VR[c]];
    /* Regressor of the next sample: inputs then outputs, each signal lag by lag (lag L: row L - 1). */
    double x[N_REGRESSORS];
    int n = 0;
    for (int c = 0; c < N_INPUTS; c++)
        for (int i = 0; i < N_INPUT_LAGS; i++) x[n++] = inputs[(INPUT_LAGS[i] - 1) * N_INPUTS + c];
    for (int c = 0; c < N_OUTPUTS; c++)
        for (int i = 0; i < N_OUTPUT_LAGS; i++) x[n++] = outputs[(OUTPUT_LAGS[i] - 1) * N_OUTPUTS + c];
    double mean[N_OUTPUTS], var[N_OUTPUTS];
    int finite = 1;
    if (free_run) {
        /* NarxPredictor.free_run_step: moment matching from the belief (x[0 .. n_u): the known regressors). */
        char *problem = NULL;
        if (!belief_step(model, state, x, mean, var, next, &problem))
            return problem != NULL ? problem : format_message("the free-run step failed (out of memory)");
    } else {
        for (int j = 0; j < N_OUTPUTS; j++) predict_output(model, &model->gp[j], x, &mean[j], &var[j]);
        memcpy(next + BELIEF_MEAN, state + BELIEF_MEAN, sizeof(double) * BELIEF_SIZE * (BELIEF_SIZE + 1));
    }
    for (int j = 0; j < N_OUTPUTS; j++) finite = finite && isfinite(mean[j]) && isfinite(var[j]);
    if (!finite) {
        char *m = number_list(mean, N_OUTPUTS), *v = number_list(var, N_OUTPUTS), *r = number_list(x, N_REGRESSORS);
        char *message = format_message("non-finite prediction %s (variance %s) at regressor %s", m ? m : "?",
                                       v ? v : "?", r ? r : "?");
        free(m), free(v), free(r);
        return message != NULL ? message : format_message("non-finite prediction");
    }
    /* Envelope (RatePredictor.advance_model, FlightgpSlave.report_envelope): warn once per excursion. */
    const int outside = report_envelope(slave, x, N_REGRESSORS, REGRESSOR_NAMES, ENVELOPE_LOW, ENVELOPE_HIGH,
                                        ENVELOPE_MARGIN, state[OUTSIDE_ENVELOPE] != 0.0, t + h,
                                        "its variance, and so the bounds, widen");
    /* Commit only after everything that can fail. */
    next[OUTSIDE_ENVELOPE] = outside ? 1.0 : 0.0;
    memcpy(state, next, sizeof(double) * MODEL_STATE_SIZE);
    set_outputs(values, mean, var);
    return NULL;
}
