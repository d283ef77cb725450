/* GP-NARX rate predictor (Bo105 GP-NARX paper, AHS 74th Forum, 2018) for a native FMU: the
 * same formulas, in the same order where it matters, as fmu_src/rate_predictor/predictor.py
 * (NarxPredictor) and fmu_src/rate_predictor/slave.py (RatePredictor), whose docstrings define the timing, the
 * regressor order, the mixture over hyperparameter samples, the bounds and the envelope.
 *
 * Model constants. The structure (signals, lags, value references, training envelope, array
 * sizes) is compiled in from model_config.h; the GP arrays are read at fmi2Instantiate from
 * resources/DATA_FILE, written by fmu_src/rate_predictor/native.py:
 *
 *   8 bytes  "FGPNARX2"
 *   8 bytes  number of doubles that follow (uint64, native byte order)
 *   doubles  per output j (d = N_REGRESSORS, m = BASIS_POINTS[j], T = DISTINCT_SAMPLES[j]):
 *              input_mean (d), input_scale (d), output_mean, output_scale, basis (m x d),
 *              then per distinct hyperparameter sample t (in order of first occurrence):
 *                weights (m), kernel_weights (d), log_signal_variance, noise_variance,
 *                variance factor V_t stored as gp_predict.h says (by columns, packed if
 *                LOWER_TRIANGULAR[j]);
 *            the joint table: per joint sample s < JOINT_SAMPLES, per output j, which distinct
 *              sample of output j it is;
 *            per output pair p = (a, b), a < b, in the order (0, 1), (0, 2), ..., (1, 2), ...:
 *              PAIR_COUNT[p] distinct sample pairs (t_a, t_b, how many joint samples hold it).
 * Annealing repeats samples (a rejected move keeps the last one: the paper's model has 100, 71
 * and 108 distinct samples of 400), so every term of one output is computed once per distinct
 * sample and counted as often as it occurs, and the covariance between two outputs once per
 * distinct pair (MomentMatcher in gp_model/uncertain_input.py does the same).
 *
 * Each instance reads its own copy (no memory shared between instances) and computes its own
 * free-run constants from it (prepare_free_run; A_t is T m^2 doubles per output, 2.3 MB for the
 * paper's model).
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
 * the distinct samples' variance factors from memory (the paper's model: 279 factors of 32 x 32,
 * 1.2 MB packed).
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
 *
 * Free-run cost. Eq. 6 takes one expm1 per pair of basis points, for every distinct sample of
 * each output and every distinct sample pair of each output pair: the paper's model has 279
 * own blocks and 487 cross blocks of 32 x 32. None of what keeps a term cheap is an
 * approximation: the known regressors have zero variance, so the exponents need the N_Z
 * uncertain ones only (3 of the paper's 5); an own block is symmetric, so 640 of its 1024 terms
 * are computed (own_block_body); expm1 is a branch-free polynomial (expm1_clamped) so that the
 * loops over a block's terms vectorise, and the column sums are accumulated four rows at a time;
 * the whole step is compiled for AVX-512 and AVX2 besides plain x86-64, picked at load. The FMU
 * then runs the formulas of MomentMatcher exactly (to rounding). Two options: the fast
 * path (exact_moments = false, the default) takes the exponents and expm1 in single precision
 * (within 2 % of the predicted standard deviation, tested), and parallel = true splits each
 * step's samples and blocks between two threads (moment_match).
 */
#define _POSIX_C_SOURCE 200809L /* clock_gettime */
#include <float.h>
#include <math.h>
#include <pthread.h>
#include <sched.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gp_predict.h"
#include "model.h"
#include "model_config.h"

#define DATA_MAGIC "FGPNARX2"
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
#define N_PRODUCTS (N_Z * (N_Z + 1) / 2)               /* products u_c u_e, c <= e, of their u */
/* Terms of a pair block of eq. 6 computed per tile (cross_block_body, own_block_body): whole rows,
   at most TILE_TERMS terms (a 32 KB tile of doubles stays in the first-level cache), or one row of
   a cross block, one band of an own block, if that is longer (prepare_free_run sizes the tile). */
#define TILE_TERMS 4096
/* Rows of a tile accumulated together (tile_accumulate): each column sum is loaded and stored once
   per ROW_GROUP rows, not once per row, a chain through memory that bounded the loop. */
#define ROW_GROUP 4
_Static_assert(ROW_GROUP == 4, "tile_accumulate's unrolled loops add four rows");
/* Rows of an own block's band (own_block_body): on the paper's model 8 rows (640 terms per
   block) measured 610-630 us per step, 16 rows (768 terms, whole vectors) 620-640, 4 rows (576
   terms, shorter loops) 650-660. */
#define OWN_BAND 8

/* One output's GP (pointers into Model.data). */
typedef struct {
    int m, T, lower_triangular;              /* basis points, distinct hyperparameter samples */
    size_t sample_size;                      /* doubles per distinct sample */
    const double *input_mean, *input_scale;  /* (d,) */
    double output_mean, output_scale;
    const double *basis;                     /* (m, d) */
    const double *samples;                   /* T blocks of sample_size doubles */
    double *signal_variance;                 /* (T,) exp(log_signal_variance) */
    double *count;                           /* (T,) joint samples that are distinct sample t */
    /* The GP in the common frame (output 0's input standardisation; frame_gp): */
    double *frame_basis;                     /* (m, d) X_a */
    double *precision;                       /* (T, d) diagonal of Lambda_a^-1 = 2 w / ratio^2 */
    double *K_inv;                           /* (T, m, m) A_t = V_t^T V_t */
    /* A step's eqs. 1-2 per distinct sample t (sample_terms), read by pair_covariance: */
    double *uz;                              /* (T, N_Z, m) u_ati on the uncertain regressors */
    double *uu;                              /* (T, N_PRODUCTS, m) u_ati,c u_ati,e for c <= e */
    double *q;                               /* (T, m) q_ati, eq. 1 */
    double *weighted;                        /* (T, m) beta_ati q_ati */
    double *M;                               /* (T, N_Z, N_Z) M_at on the uncertain regressors */
    double *log_det;                         /* (T,) ln|I + T_at| (eq. 6) */
    double *mean;                            /* (T,) E[f_a] of sample t, standardised */
} OutputGP;

/* One output pair a < b: its distinct sample pairs (pointers into Model.data). */
typedef struct {
    int a, b, n;
    const double *combos;                    /* (n, 3): t_a, t_b, joint samples holding it */
} SamplePairs;

/* Scratch of woodbury_terms (at most N_Z x N_Z each). */
typedef struct {
    double root[N_Z], T[N_Z * N_Z], L[N_Z * N_Z], Y[N_Z * N_Z];
} WoodburyScratch;

/* One thread's scratch for its share of a free-run step (moment_match_share), and its partial
 * sums over the samples and pair blocks it took. */
typedef struct {
    double *u_M;                                      /* (N_Z, m_max) */
    double *tile;                                     /* a pair block's tile (PairBlock) */
    float *tile_single;                               /* the same in single precision */
    float *columns_single;                            /* ((N_Z + 1) m_max,) PairBlock.columns_single */
    double *column_sum, *column_trace;                /* (m_max,) */
    double *half_a, *half_b;                          /* (m_max,) */
    WoodburyScratch woodbury;
    double cov_sum[N_OUTPUTS * N_OUTPUTS];            /* sum of count-weighted covariances (standardised) */
    double cross_sum[D * N_OUTPUTS];                  /* sum of count-weighted Cov[x, f_a] (standardised) */
    int samples_failed, failed;                       /* a Cholesky factor of eq. 6 failed (samples; blocks) */
} Scratch;

/* One pair block of a step: output a's distinct sample t_a with output b's t_b (a == b and t_a
 * == t_b: an own block), counted `weight` times (joint samples holding it). */
typedef struct {
    int a, t_a, b, t_b;
    double weight;
} PairJob;

/* The free run's threads (moment_match): the second one (worker_main) is started at the
 * first step with parallel = true and stopped by model_free. It waits on `start` for a new
 * `generation`, computes its share and publishes the generation in `finished`. */
#define THREADS 2
typedef struct {
    pthread_t thread;
    pthread_mutex_t lock;
    pthread_cond_t start;
    int running, quit, refused;                      /* refused: pthread_create failed (not retried) */
    unsigned generation, finished;                    /* changed atomically (generation also under lock) */
    unsigned barrier_count, barrier_phase;            /* the spin barrier between a share's phases */
} Worker;

struct Model {
    double *data;
    OutputGP gp[N_OUTPUTS];
    const double *joint;                              /* (JOINT_SAMPLES, N_OUTPUTS) */
    SamplePairs pairs[N_PAIRS > 0 ? N_PAIRS : 1];
    double *squared;                                  /* scratch (m_max, d) */
    double *k, *v;                                    /* scratch (m_max,) */
    /* free-run scratch */
    double *sample_means;                             /* (JOINT_SAMPLES, N_OUTPUTS) mixture components */
    Scratch scratch[THREADS];                         /* one per thread */
    int single_precision;                             /* the step's pair blocks: !exact_moments */
    int threads;                                      /* the step's threads: 2 if parallel (and started) */
    double frame_mean[D], frame_scale[D];             /* output 0's input standardisation */
    PairJob *pair_jobs;                               /* the own blocks, then each output pair's */
    int n_sample_jobs, n_pair_jobs;
    int sample_split[THREADS], pair_split[THREADS];    /* where each thread's share of the jobs begins */
    double step_m[D], step_S_z[N_Z * N_Z];            /* the step's standardised regressor belief */
    Worker worker;
    double next_state[MODEL_STATE_SIZE];              /* a step's result before its commit */
};

static void stop_worker(Model *model); /* below */

void model_free(Model *model) {
    if (model == NULL) return;
    stop_worker(model); /* before anything it reads is freed */
    for (int j = 0; j < N_OUTPUTS; j++) {
        OutputGP *gp = &model->gp[j];
        free(gp->signal_variance);
        free(gp->count);
        free(gp->frame_basis);
        free(gp->precision);
        free(gp->K_inv);
        free(gp->uz);
        free(gp->uu);
        free(gp->q);
        free(gp->weighted);
        free(gp->M);
        free(gp->log_det);
        free(gp->mean);
    }
    free(model->data);
    free(model->squared);
    free(model->k);
    free(model->v);
    free(model->sample_means);
    for (int k = 0; k < THREADS; k++) {
        Scratch *scratch = &model->scratch[k];
        free(scratch->u_M);
        free(scratch->tile);
        free(scratch->tile_single);
        free(scratch->columns_single);
        free(scratch->column_sum);
        free(scratch->column_trace);
        free(scratch->half_a);
        free(scratch->half_b);
    }
    free(model->pair_jobs);
    free(model);
}

static Model *fail(Model *model, char **error, char *message) {
    *error = message;
    model_free(model);
    return NULL;
}

/* The free run's constants and scratch (fmu_src/rate_predictor/predictor.py, _moment_matcher): every output's
 * GP in output 0's input frame, z_0 = (s_a z_a + mu_a - mu_0) / s_0 (frame_gp: basis * ratio +
 * offset, precision 2 w / ratio^2), and A_t = V_t^T V_t from the stored variance factors (by
 * columns, packed if lower triangular). Returns 0 if out of memory. */
static int prepare_free_run(Model *model, int m_max) {
    const OutputGP *lead = &model->gp[0];
    for (int c = 0; c < D; c++) {
        model->frame_mean[c] = lead->input_mean[c];
        model->frame_scale[c] = lead->input_scale[c];
    }
    double *dense = malloc(sizeof(double) * (size_t)m_max * (size_t)m_max); /* V_t, row-major */
    model->sample_means = malloc(sizeof(double) * (size_t)JOINT_SAMPLES * N_OUTPUTS);
    int ok = dense != NULL && model->sample_means != NULL;
    /* a tile holds TILE_TERMS terms, or one band of an own block (OWN_BAND x m) if that is more */
    const size_t band_terms = (size_t)OWN_BAND * (size_t)m_max;
    const size_t tile_terms = band_terms > TILE_TERMS ? band_terms : TILE_TERMS;
    for (int k = 0; k < THREADS; k++) {
        Scratch *scratch = &model->scratch[k];
        scratch->u_M = malloc(sizeof(double) * (size_t)m_max * N_Z);
        scratch->tile = malloc(sizeof(double) * tile_terms);
        scratch->tile_single = malloc(sizeof(float) * tile_terms);
        scratch->columns_single = malloc(sizeof(float) * (N_Z + 1) * (size_t)m_max);
        scratch->column_sum = malloc(sizeof(double) * (size_t)m_max);
        scratch->column_trace = malloc(sizeof(double) * (size_t)m_max);
        scratch->half_a = malloc(sizeof(double) * (size_t)m_max);
        scratch->half_b = malloc(sizeof(double) * (size_t)m_max);
        ok = ok && scratch->u_M != NULL && scratch->tile != NULL && scratch->tile_single != NULL
             && scratch->columns_single != NULL && scratch->column_sum != NULL && scratch->column_trace != NULL
             && scratch->half_a != NULL && scratch->half_b != NULL;
    }
    for (int j = 0; j < N_OUTPUTS && ok; j++) {
        OutputGP *gp = &model->gp[j];
        const size_t m = (size_t)gp->m, T = (size_t)gp->T;
        gp->frame_basis = malloc(sizeof(double) * m * D);
        gp->precision = malloc(sizeof(double) * T * D);
        gp->K_inv = malloc(sizeof(double) * T * m * m);
        gp->uz = malloc(sizeof(double) * T * N_Z * m);
        gp->uu = malloc(sizeof(double) * T * N_PRODUCTS * m);
        gp->q = malloc(sizeof(double) * T * m);
        gp->weighted = malloc(sizeof(double) * T * m);
        gp->M = malloc(sizeof(double) * T * N_Z * N_Z);
        gp->log_det = malloc(sizeof(double) * T);
        gp->mean = malloc(sizeof(double) * T);
        ok = gp->frame_basis != NULL && gp->precision != NULL && gp->K_inv != NULL && gp->uz != NULL && gp->uu != NULL
             && gp->q != NULL && gp->weighted != NULL && gp->M != NULL && gp->log_det != NULL && gp->mean != NULL;
        if (!ok) break;
        double ratio[D], offset[D];
        for (int c = 0; c < D; c++) {
            ratio[c] = gp->input_scale[c] / model->frame_scale[c]; /* exactly 1 for output 0 */
            offset[c] = (gp->input_mean[c] - model->frame_mean[c]) / model->frame_scale[c];
        }
        for (size_t i = 0; i < m; i++)
            for (int c = 0; c < D; c++) gp->frame_basis[i * D + c] = gp->basis[i * D + c] * ratio[c] + offset[c];
        for (size_t t = 0; t < T; t++) {
            const double *sample = gp->samples + t * gp->sample_size;
            const double *kernel_weights = sample + m, *factor = sample + m + D + 2;
            for (int c = 0; c < D; c++) gp->precision[t * D + c] = 2.0 * kernel_weights[c] / (ratio[c] * ratio[c]);
            /* unpack V_t (stored by columns) into dense[row * m + column] */
            for (size_t column = 0; column < m; column++)
                for (size_t row = 0; row < m; row++) {
                    int stored = !gp->lower_triangular || row >= column;
                    dense[row * m + column] = stored ? *factor++ : 0.0;
                }
            /* A_t[i][k] = sum_r V_t[r][i] V_t[r][k] (frame_gp: einsum "sji,sjk->sik") */
            double *A = gp->K_inv + t * m * m;
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

/* A pair block's cost in terms of eq. 6 (own_block_body, cross_block_body), plus its set-up
 * (Woodbury factor, quadratic forms) counted as BLOCK_SET_UP_TERMS: measured on the paper's model,
 * a step's set-up took 93 us for 766 blocks, about what 170 terms of a block take. */
#define BLOCK_SET_UP_TERMS 170.0

/* The rows of the band of an own block (m x m) that begins at row first. */
static inline int band_rows(int m, int first) { return m - first < OWN_BAND ? m - first : OWN_BAND; }

static double pair_job_cost(const Model *model, const PairJob *job) {
    const int ma = model->gp[job->a].m, mb = model->gp[job->b].m;
    if (job->a != job->b) return (double)ma * mb + BLOCK_SET_UP_TERMS;
    double terms = 0.0;
    for (int first = 0; first < ma; first += OWN_BAND) terms += (double)band_rows(ma, first) * (ma - first);
    return terms + BLOCK_SET_UP_TERMS;
}

/* The index of the first job of the second thread's share: where the running cost reaches half
 * the total. */
static int half_way(const double *costs, int n) {
    double total = 0.0, running = 0.0;
    for (int j = 0; j < n; j++) total += costs[j];
    int j = 0;
    while (j < n && running + costs[j] <= 0.5 * total) running += costs[j++];
    return j;
}

/* The free run's jobs: the pair blocks (pair_covariance) in the order of MomentMatcher's loops,
 * each output's own blocks (one per distinct sample, so the first n_sample_jobs are also the
 * sample jobs of sample_terms), then each output pair's distinct sample pairs; and where the
 * second thread's shares begin, split by cost. Returns 0 if out of memory. */
static int prepare_jobs(Model *model) {
    int n_samples = 0, n_pairs = 0;
    for (int a = 0; a < N_OUTPUTS; a++) n_samples += model->gp[a].T;
    n_pairs = n_samples;
    for (int p = 0; p < N_PAIRS; p++) n_pairs += model->pairs[p].n;
    model->pair_jobs = malloc(sizeof(PairJob) * (size_t)n_pairs);
    double *costs = malloc(sizeof(double) * (size_t)n_pairs);
    if (model->pair_jobs == NULL || costs == NULL) {
        free(costs);
        return 0;
    }
    int j = 0;
    for (int a = 0; a < N_OUTPUTS; a++)
        for (int t = 0; t < model->gp[a].T; t++, j++) {
            model->pair_jobs[j] = (PairJob){a, t, a, t, model->gp[a].count[t]};
            costs[j] = model->gp[a].m;
        }
    model->n_sample_jobs = n_samples;
    model->sample_split[0] = 0, model->sample_split[1] = half_way(costs, n_samples);
    for (int p = 0; p < N_PAIRS; p++)
        for (int k = 0; k < model->pairs[p].n; k++, j++) {
            const double *combo = model->pairs[p].combos + 3 * k;
            model->pair_jobs[j] = (PairJob){model->pairs[p].a, (int)combo[0], model->pairs[p].b, (int)combo[1], combo[2]};
        }
    model->n_pair_jobs = n_pairs;
    for (j = 0; j < n_pairs; j++) costs[j] = pair_job_cost(model, &model->pair_jobs[j]);
    model->pair_split[0] = 0, model->pair_split[1] = half_way(costs, n_pairs);
    free(costs);
    return 1;
}

/* The joint table and the sample pairs (layout above), checked: every index names a distinct
 * sample of its output, and each pair's counts sum to JOINT_SAMPLES. Returns NULL or a
 * malloc'd message. */
static char *read_mixture(Model *model, const double *p) {
    model->joint = p;
    p += (size_t)JOINT_SAMPLES * N_OUTPUTS;
    for (int j = 0; j < N_OUTPUTS; j++) {
        OutputGP *gp = &model->gp[j];
        gp->count = calloc((size_t)gp->T, sizeof(double));
        if (gp->count == NULL) return format_message("out of memory");
        for (int s = 0; s < JOINT_SAMPLES; s++) {
            double t = model->joint[(size_t)s * N_OUTPUTS + j];
            if (!(t >= 0.0 && t < gp->T && t == floor(t)))
                return format_message("corrupt %s: joint sample %d names sample %g of output %d, which has %d",
                                      DATA_FILE, s, t, j, gp->T);
            gp->count[(int)t] += 1.0;
        }
    }
    int index = 0;
    for (int a = 0; a < N_OUTPUTS; a++)
        for (int b = a + 1; b < N_OUTPUTS; b++, index++) {
            SamplePairs *pair = &model->pairs[index];
            pair->a = a, pair->b = b, pair->n = PAIR_COUNT[index], pair->combos = p;
            double total = 0.0;
            for (int k = 0; k < pair->n; k++) {
                const double *combo = p + 3 * k;
                if (!(combo[0] >= 0.0 && combo[0] < model->gp[a].T && combo[0] == floor(combo[0]) && combo[1] >= 0.0
                      && combo[1] < model->gp[b].T && combo[1] == floor(combo[1]) && combo[2] >= 1.0))
                    return format_message("corrupt %s: sample pair %d of outputs %d and %d is (%g, %g, %g)", DATA_FILE,
                                          k, a, b, combo[0], combo[1], combo[2]);
                total += combo[2];
            }
            if (total != JOINT_SAMPLES)
                return format_message("corrupt %s: the sample pairs of outputs %d and %d count %g joint samples, "
                                      "not %d", DATA_FILE, a, b, total, JOINT_SAMPLES);
            p += 3 * (size_t)pair->n;
        }
    return NULL;
}

static void select_moment_match(void); /* the free run's step compiled per instruction set (below) */
/* select_moment_match runs once per process, whatever number of instances load at once. */
static pthread_once_t moment_match_selected = PTHREAD_ONCE_INIT;

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
        gp->T = DISTINCT_SAMPLES[j];
        gp->lower_triangular = LOWER_TRIANGULAR[j];
        size_t m = (size_t)gp->m;
        gp->sample_size = m + N_REGRESSORS + 2 + gp_factor_size(gp->m, gp->lower_triangular);
        gp->input_mean = p, p += N_REGRESSORS;
        gp->input_scale = p, p += N_REGRESSORS;
        gp->output_mean = *p++;
        gp->output_scale = *p++;
        gp->basis = p, p += (size_t)gp->m * N_REGRESSORS;
        gp->samples = p, p += (size_t)gp->T * gp->sample_size;
        gp->signal_variance = malloc(sizeof(double) * (size_t)gp->T);
        if (gp->signal_variance == NULL) return fail(model, error, NULL);
        for (int t = 0; t < gp->T; t++)
            gp->signal_variance[t] = exp(gp->samples[(size_t)t * gp->sample_size + m + N_REGRESSORS]);
        if (gp->m > m_max) m_max = gp->m;
    }
    char *problem = read_mixture(model, p);
    if (problem != NULL) return fail(model, error, problem);
    model->squared = malloc(sizeof(double) * (size_t)m_max * N_REGRESSORS);
    model->k = malloc(sizeof(double) * (size_t)m_max);
    model->v = malloc(sizeof(double) * (size_t)m_max);
    if (model->squared == NULL || model->k == NULL || model->v == NULL) return fail(model, error, NULL);
    if (!prepare_free_run(model, m_max)) return fail(model, error, NULL);
    if (!prepare_jobs(model)) return fail(model, error, NULL);
    model->threads = 1;
    pthread_once(&moment_match_selected, select_moment_match);
    return model;
}

/* Mean and variance (measurement noise included) of output gp at regressor x (physical
 * units): the mixture over its hyperparameter samples (predictor.py, _Block.predict), each
 * distinct sample's mean and latent variance by gp_predict.c, counted as often as it occurs. */
static void predict_output(const Model *model, const OutputGP *gp, const double x[N_REGRESSORS],
                           double *mean_out, double *var_out) {
    const int m = gp->m, d = N_REGRESSORS;
    double xs[N_REGRESSORS];
    gp_standardise(d, x, gp->input_mean, gp->input_scale, xs);
    gp_squared_distances(m, d, xs, gp->basis, model->squared);
    double sum_mean = 0.0, sum_second = 0.0; /* over the joint samples: each distinct one count[t] times */
    for (int s = 0; s < gp->T; s++) {
        const double *sample = gp->samples + (size_t)s * gp->sample_size;
        const double *weights = sample, *kernel_weights = sample + m;
        const double log_signal_variance = sample[m + d], noise_variance = sample[m + d + 1];
        const double *factor = sample + m + d + 2;
        gp_kernel_row(m, d, model->squared, kernel_weights, log_signal_variance, model->k);
        const double mu = gp_mean(m, model->k, weights, 1);
        const double variance = gp_latent_variance(m, factor, gp->lower_triangular, model->k,
                                                   gp->signal_variance[s], model->v) + noise_variance;
        sum_mean += gp->count[s] * mu;
        sum_second += gp->count[s] * (variance + mu * mu);
    }
    const double mean = sum_mean / JOINT_SAMPLES;
    *mean_out = mean * gp->output_scale + gp->output_mean;
    *var_out = gp_spread(sum_second / JOINT_SAMPLES, mean) * gp->output_scale * gp->output_scale;
}

/* -- free run: moment matching (gp_model/uncertain_input.py) ----------------------------- */

/* _woodbury_terms on the uncertain regressors: M(P) = (P + S^-1)^-1 = P^-1/2 (I + T)^-1 T P^-1/2
 * with T = P^1/2 S P^1/2, and ln|I + T| (eq. 6), for a positive diagonal precision P (N_Z,) and
 * the standardised covariance S (N_Z x N_Z, symmetric positive semi-definite, may be singular) of
 * the uncertain regressors. The known regressors have zero variance, so on them T is zero, I + T
 * the identity and M zero: eqs. 1-6 need the N_Z x N_Z block only. I + T has all eigenvalues
 * >= 1, so its Cholesky factor exists; returns 0 if it does not (S is then far from positive
 * semi-definite: a bug, refused as a step). M is symmetrised as there. */
static inline __attribute__((always_inline)) int woodbury_terms(WoodburyScratch *w, const double precision[N_Z], const double S[N_Z * N_Z],
                          double M[N_Z * N_Z], double *log_det) {
    double *root = w->root, *T = w->T, *L = w->L, *Y = w->Y;
    for (int i = 0; i < N_Z; i++) root[i] = sqrt(precision[i]);
    for (int i = 0; i < N_Z; i++)
        for (int j = 0; j < N_Z; j++) T[i * N_Z + j] = S[i * N_Z + j] * (root[i] * root[j]);
    /* L L^T = I + T (Cholesky, lower) */
    double determinant = 1.0; /* |I + T|, the product of the pivots: each >= 1 up to rounding */
    for (int j = 0; j < N_Z; j++) {
        double pivot = 1.0 + T[j * N_Z + j];
        for (int k = 0; k < j; k++) pivot -= L[j * N_Z + k] * L[j * N_Z + k];
        if (!(pivot > 0.0)) return 0;
        L[j * N_Z + j] = sqrt(pivot);
        determinant *= pivot;
        for (int i = j + 1; i < N_Z; i++) {
            double value = T[i * N_Z + j];
            for (int k = 0; k < j; k++) value -= L[i * N_Z + k] * L[j * N_Z + k];
            L[i * N_Z + j] = value / L[j * N_Z + j];
        }
        for (int i = 0; i < j; i++) L[i * N_Z + j] = 0.0;
    }
    /* Y = L^-1 T (forward substitution), then M P^1/2..P^1/2 = L^-T Y (back substitution), in M */
    for (int c = 0; c < N_Z; c++) {
        for (int i = 0; i < N_Z; i++) {
            double value = T[i * N_Z + c];
            for (int k = 0; k < i; k++) value -= L[i * N_Z + k] * Y[k * N_Z + c];
            Y[i * N_Z + c] = value / L[i * N_Z + i];
        }
        for (int i = N_Z - 1; i >= 0; i--) {
            double value = Y[i * N_Z + c];
            for (int k = i + 1; k < N_Z; k++) value -= L[k * N_Z + i] * M[k * N_Z + c];
            M[i * N_Z + c] = value / L[i * N_Z + i];
        }
    }
    for (int i = 0; i < N_Z; i++)
        for (int j = 0; j < N_Z; j++) M[i * N_Z + j] /= root[i] * root[j];
    for (int i = 0; i < N_Z; i++)
        for (int j = i + 1; j < N_Z; j++)
            M[i * N_Z + j] = M[j * N_Z + i] = 0.5 * (M[i * N_Z + j] + M[j * N_Z + i]);
    *log_det = log(determinant);
    return 1;
}

/* u^T M u for u (N_Z,), entry c at u[c * stride], and a symmetric M (N_Z x N_Z). */
static inline __attribute__((always_inline)) double quadratic_form(const double *u, size_t stride, const double M[N_Z * N_Z]) {
    double total = 0.0;
    for (int i = 0; i < N_Z; i++) {
        double row = 0.0;
        for (int j = 0; j < N_Z; j++) row += M[i * N_Z + j] * u[j * stride];
        total += row * u[i * stride];
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

/* -- the pair blocks of eq. 6, vectorised ---------------------------------------------------- */

/* Cody and Waite's split of ln 2 (the high part has trailing zero bits, so k ln2_hi is exact for
 * |k| < 2^11), 1 / ln 2, and 1.5 * 2^52, which rounds a double below 2^51 in magnitude to an
 * integer held in the low bits of its mantissa. */
#define LN2_HI 6.93147180369123816490e-01
#define LN2_LO 1.90821492927058770002e-10
#define INV_LN2 1.44269504088896338700e+00
#define ROUNDING_SHIFT 6755399441055744.0
/* The argument's bound: expm1 is -1 to double precision below -EXPM1_BOUND, and eq. 6's exponents
 * stay far below +EXPM1_BOUND (a q_ai q_bj of e^700 would have overflowed eq. 1 long before). */
#define EXPM1_BOUND 700.0

/* expm1(x) without branches or library calls, so that gcc vectorises the loops that call it:
 * x = k ln2 + r with k = round(x / ln2) and |r| <= ln2 / 2; expm1(r) by its Taylor series to
 * r^14 / 14! (the first term left out is below 1.1e-17 |expm1(r)| for |r| <= 0.347: Horner's
 * rounding dominates, a few ulp); expm1(x) = 2^k expm1(r) + (2^k - 1), which for k = 0 is
 * expm1(r) itself, so the relative accuracy holds for tiny x, where exp(x) - 1 would lose it.
 * 2^k is built in the exponent bits from the rounded k (k + 1023 in [13, 2033]). The argument is
 * clamped to [-EXPM1_BOUND, EXPM1_BOUND] first (clamp_double): in the pair blocks that is done
 * where the exponents are written (tile_exponents), because a clamp inside the loop over expm1
 * made gcc mask the whole polynomial for the clamped lanes. reduced_expm1 returns expm1(r) and
 * sets 2^k; expm1_clamped combines them. Checked against libm's expm1 in the tests: 2 ulp at
 * most over [-EXPM1_BOUND, EXPM1_BOUND], the test allows 4. */
static inline __attribute__((always_inline)) double clamp_double(double x) {
    x = x < -EXPM1_BOUND ? -EXPM1_BOUND : x;
    return x > EXPM1_BOUND ? EXPM1_BOUND : x;
}

static inline __attribute__((always_inline)) double reduced_expm1(double x, double *two_k) {
    double shifted = x * INV_LN2 + ROUNDING_SHIFT;
    int64_t bits;
    memcpy(&bits, &shifted, sizeof bits);
    const double k = shifted - ROUNDING_SHIFT;
    const double r = (x - k * LN2_HI) - k * LN2_LO;
    double p = 1.0 / 87178291200.0; /* 1/14! */
    p = p * r + 1.0 / 6227020800.0;
    p = p * r + 1.0 / 479001600.0;
    p = p * r + 1.0 / 39916800.0;
    p = p * r + 1.0 / 3628800.0;
    p = p * r + 1.0 / 362880.0;
    p = p * r + 1.0 / 40320.0;
    p = p * r + 1.0 / 5040.0;
    p = p * r + 1.0 / 720.0;
    p = p * r + 1.0 / 120.0;
    p = p * r + 1.0 / 24.0;
    p = p * r + 1.0 / 6.0;
    p = p * r + 0.5;
    const int64_t exponent = (bits + 1023) << 52; /* the low 12 bits of bits hold k mod 2^12 */
    memcpy(two_k, &exponent, sizeof *two_k);
    return p * (r * r) + r; /* expm1(r) */
}

static inline __attribute__((always_inline)) double expm1_clamped(double x) {
    double two_k;
    const double p = reduced_expm1(x, &two_k);
    return two_k * p + (two_k - 1.0);
}

/* exp(x) = 2^k (1 + expm1(r)) by the same steps (relative accuracy a few ulp; an argument below
 * -EXPM1_BOUND gives exp(-EXPM1_BOUND), about 1e-304, for 0): eq. 1's q_ai (sample_terms). */
static inline __attribute__((always_inline)) double exp_branchless(double x) {
    double two_k;
    const double p = reduced_expm1(clamp_double(x), &two_k);
    return two_k * (1.0 + p);
}

/* expm1 in single precision, the steps of expm1_clamped in float: Taylor series to r^7 / 7!
 * (the first term left out is below 6e-9 |expm1(r)|, a tenth of float's rounding), 2^k in
 * float's exponent bits (k + 127 in [1, 253] for |x| <= SINGLE_BOUND, clamp_single). Relative
 * error a few float ulp (about 1e-7): the fast path's pair blocks (single_precision). */
#define SINGLE_BOUND 87.0f
static inline __attribute__((always_inline)) float clamp_single(float x) {
    x = x < -SINGLE_BOUND ? -SINGLE_BOUND : x;
    return x > SINGLE_BOUND ? SINGLE_BOUND : x;
}

static inline __attribute__((always_inline)) float expm1_single_clamped(float x) {
    const float shifted = x * 1.44269504f + 12582912.0f; /* 1.5 * 2^23 */
    int32_t bits;
    memcpy(&bits, &shifted, sizeof bits);
    const float k = shifted - 12582912.0f;
    const float r = (x - k * 0.693145752f) - k * 1.42860677e-6f; /* ln 2 split for float */
    float p = 1.0f / 5040.0f;
    p = p * r + 1.0f / 720.0f;
    p = p * r + 1.0f / 120.0f;
    p = p * r + 1.0f / 24.0f;
    p = p * r + 1.0f / 6.0f;
    p = p * r + 0.5f;
    p = p * (r * r) + r;
    const int32_t exponent = (bits + 127) << 23;
    float two_k;
    memcpy(&two_k, &exponent, sizeof two_k);
    return two_k * p + (two_k - 1.0f);
}

/* The loops over a pair block's terms below vectorise (the clamps becoming minima and maxima,
 * and gcc told that a row's small array of N_Z numbers does not alias them) only under OpenMP's
 * SIMD directive, on when built with -fopenmp-simd -DFLIGHTGP_OPENMP_SIMD (native.py, MODEL_FLAGS);
 * without it (e.g. rebuilt from these sources by other tools) they may run scalar, with the same
 * results. */
#ifdef FLIGHTGP_OPENMP_SIMD
#define SIMD_LOOP _Pragma("omp simd")
#else
#define SIMD_LOOP
#endif

/* The arrays of one pair block (pair_covariance): rows i of output a's sample, columns j of
 * output b's, N_Z uncertain regressors. */
typedef struct {
    int ma, mb;
    const double *half_a, *half_b;  /* (ma,), (mb,) the exponent's parts of i and of j alone */
    const double *u_M, *u_b;        /* (N_Z, ma) M_ab u_ai, (N_Z, mb) u_bj */
    const double *weighted_a, *weighted_b; /* (ma,), (mb,) beta q */
    const double *K_inv, *q;        /* a == b only: (m, m) A_t and (m,) q_t */
    double *tile;                   /* scratch (max(TILE_TERMS, OWN_BAND m),): expm1(D_ij) of a tile */
    float *tile_single;             /* the same in single precision */
    float *columns_single;          /* scratch ((N_Z + 1) mb,): half_b and u_b in float (single) */
    double *column_sum, *column_trace; /* scratch (mb,) */
} PairBlock;

/* A block's terms are computed in tiles of rows (rows first.. of the block, each from column
 * first_column on), in passes that each are one loop gcc vectorises without reordering a sum (so
 * without SIMD reductions): the exponents (tile_exponents), expm1 over the tile as one flat array
 * (tile_expm1), then the rows accumulated per column (tile_accumulate). single: the exponents
 * and expm1 in float, 16 (8) lanes wide where double has 8 (4), from float copies of the
 * columns' arrays (columns_to_single); the sums in double. */

/* half_b and u_b in float, for the exponents of the single-precision path. */
static inline __attribute__((always_inline)) void columns_to_single(const PairBlock *block) {
    const int mb = block->mb;
    float *restrict half_b = block->columns_single, *restrict u_b = block->columns_single + mb;
    for (int j = 0; j < mb; j++) half_b[j] = (float)block->half_b[j];
    for (int k = 0; k < N_Z * mb; k++) u_b[k] = (float)block->u_b[k];
}

/* The exponents D_ij (eq. 6), clamped for expm1, of rows i = first + r < first + rows and columns
 * j >= first_column: half_a_i + half_b_j + (M_ab u_ai) . u_bj, at tile[at + r L + j -
 * first_column] with L = mb - first_column. */
static inline __attribute__((always_inline)) void tile_exponents(const PairBlock *block, int single, size_t at,
                                                                 int first, int rows, int first_column) {
    const int ma = block->ma, mb = block->mb, L = mb - first_column;
    for (int r = 0; r < rows; r++) {
        const int i = first + r;
        if (single) {
            const float *restrict half_b = block->columns_single, *restrict u_b = block->columns_single + mb;
            float *restrict out = block->tile_single + at + (size_t)r * L;
            float x[N_Z];
            for (int c = 0; c < N_Z; c++) x[c] = (float)block->u_M[c * ma + i];
            const float half_a = (float)block->half_a[i];
SIMD_LOOP
            for (int j = first_column; j < mb; j++) {
                float exponent = half_a + half_b[j];
#pragma GCC unroll 16
                for (int c = 0; c < N_Z; c++) exponent += x[c] * u_b[c * mb + j];
                out[j - first_column] = clamp_single(exponent);
            }
        } else {
            const double *restrict half_b = block->half_b, *restrict u_b = block->u_b;
            double *restrict out = block->tile + at + (size_t)r * L;
            double x[N_Z];
            for (int c = 0; c < N_Z; c++) x[c] = block->u_M[c * ma + i];
            const double half_a = block->half_a[i];
SIMD_LOOP
            for (int j = first_column; j < mb; j++) {
                double exponent = half_a + half_b[j];
#pragma GCC unroll 16
                for (int c = 0; c < N_Z; c++) exponent += x[c] * u_b[c * mb + j];
                out[j - first_column] = clamp_double(exponent);
            }
        }
    }
}

/* The tile's first `terms` (clamped) exponents replaced by their expm1. */
static inline __attribute__((always_inline)) void tile_expm1(const PairBlock *block, int single, size_t terms) {
    if (single) {
        float *restrict tile = block->tile_single;
SIMD_LOOP
        for (size_t k = 0; k < terms; k++) tile[k] = expm1_single_clamped(tile[k]);
    } else {
        double *restrict tile = block->tile;
SIMD_LOOP
        for (size_t k = 0; k < terms; k++) tile[k] = expm1_clamped(tile[k]);
    }
}

/* Rows first.. (< first + rows) of the tile as tile_exponents wrote them at `at` (now expm1(D_ij)),
 * added per column j in [begin, mb), the columns [begin, begin + halved) at half weight:
 * column_sum_j += w_ai expm1(D_ij) and, own, column_trace_j += q_i A_ij (1 + expm1(D_ij)) (eq. 4's
 * trace). ROW_GROUP rows at a time, so that a column's sums are loaded and stored once per group:
 * one row at a time, that chain through memory bounded the loop. */
static inline __attribute__((always_inline)) void tile_accumulate(const PairBlock *block, int single, int own,
                                                                  size_t at, int first, int rows, int first_column,
                                                                  int halved) {
    const int mb = block->mb, L = mb - first_column;
    double *restrict column_sum = block->column_sum, *restrict column_trace = block->column_trace;
    for (int r = 0; r < rows; r += ROW_GROUP) {
        const int group = rows - r < ROW_GROUP ? rows - r : ROW_GROUP, i = first + r;
        const double *restrict A = own ? block->K_inv + (size_t)i * mb : NULL;
        const double *restrict excess = block->tile + at + (size_t)r * L; /* column j at j - first_column */
        const float *restrict excess_single = block->tile_single + at + (size_t)r * L;
#define EXCESS(g, j) (single ? (double)excess_single[(g) * L + (j) - first_column] \
                            : excess[(g) * L + (j) - first_column])
        for (int part = 0; part < 2; part++) { /* the halved columns, then the rest */
            const int begin = part == 0 ? first_column : first_column + halved;
            const int end = part == 0 ? first_column + halved : mb;
            const double weight = part == 0 ? 0.5 : 1.0;
            double w[ROW_GROUP] = {0.0}, q[ROW_GROUP] = {0.0};
            for (int g = 0; g < group; g++) {
                w[g] = weight * block->weighted_a[i + g];
                if (own) q[g] = weight * block->q[i + g];
            }
            if (group == ROW_GROUP && own) {
SIMD_LOOP
                for (int j = begin; j < end; j++) {
                    const double v0 = EXCESS(0, j), v1 = EXCESS(1, j), v2 = EXCESS(2, j), v3 = EXCESS(3, j);
                    column_sum[j] += w[0] * v0 + w[1] * v1 + w[2] * v2 + w[3] * v3;
                    column_trace[j] += q[0] * A[j] * (1.0 + v0) + q[1] * A[mb + j] * (1.0 + v1)
                                       + q[2] * A[2 * mb + j] * (1.0 + v2) + q[3] * A[3 * mb + j] * (1.0 + v3);
                }
            } else if (group == ROW_GROUP) {
SIMD_LOOP
                for (int j = begin; j < end; j++)
                    column_sum[j] += w[0] * EXCESS(0, j) + w[1] * EXCESS(1, j) + w[2] * EXCESS(2, j) + w[3] * EXCESS(3, j);
            } else {
                for (int g = 0; g < group; g++) {
SIMD_LOOP
                    for (int j = begin; j < end; j++) {
                        column_sum[j] += w[g] * EXCESS(g, j);
                        if (own) column_trace[j] += q[g] * A[g * mb + j] * (1.0 + EXCESS(g, j));
                    }
                }
            }
        }
#undef EXCESS
    }
}

/* A cross block (a != b; ma x mb): returns sum_j w_bj column_sum_j
 * = sum_ij w_ai w_bj expm1(D_ij), over tiles of at most TILE_TERMS terms (whole rows). */
static inline __attribute__((always_inline)) double cross_block_body(const PairBlock *block, int single) {
    const int ma = block->ma, mb = block->mb;
    const int rows_per_tile = mb >= TILE_TERMS ? 1 : TILE_TERMS / mb;
    for (int j = 0; j < mb; j++) block->column_sum[j] = 0.0;
    if (single) columns_to_single(block);
    for (int first = 0; first < ma; first += rows_per_tile) {
        const int rows = ma - first < rows_per_tile ? ma - first : rows_per_tile;
        tile_exponents(block, single, 0, first, rows, 0);
        tile_expm1(block, single, (size_t)rows * mb);
        tile_accumulate(block, single, 0, 0, first, rows, 0, 0);
    }
    double sum = 0.0;
    for (int j = 0; j < mb; j++) sum += block->column_sum[j] * block->weighted_b[j];
    return sum;
}

/* An own block (a == b, the same sample t; m x m): returns sum_ij w_i w_j expm1(D_ij) and sets
 * *trace = sum_ij q_i q_j A_ij (1 + expm1(D_ij)) = tr(A_t Q^aa) (eq. 4). Both summands are
 * symmetric in i and j (D_ij = D_ji, as M_ab is symmetric and half_b is half_a less the
 * constant; A_t is symmetric), so each band of OWN_BAND rows takes the columns from its first
 * row on: the square on the diagonal at half weight (it holds both (i, j) and (j, i)), and both
 * sums are doubled at the end. Bands are packed into tiles of at most TILE_TERMS terms (one band
 * if longer). The paper's 32 x 32 block is then 640 terms instead of 1024 (one tile), and about
 * half of A_t is read. */
static inline __attribute__((always_inline)) double own_block_body(const PairBlock *block, double *trace, int single) {
    const int m = block->ma;
    for (int j = 0; j < m; j++) block->column_sum[j] = 0.0, block->column_trace[j] = 0.0;
    if (single) columns_to_single(block);
    for (int first = 0; first < m;) { /* one tile: bands first .. last - 1 */
        int last = first;
        size_t terms = 0;
        while (last < m) {
            const int rows = band_rows(m, last);
            const size_t band_terms = (size_t)rows * (size_t)(m - last);
            if (last > first && terms + band_terms > TILE_TERMS) break;
            tile_exponents(block, single, terms, last, rows, last);
            terms += band_terms;
            last += rows;
        }
        tile_expm1(block, single, terms);
        for (size_t at = 0; first < last; first += OWN_BAND) {
            const int rows = band_rows(m, first);
            tile_accumulate(block, single, 1, at, first, rows, first, rows);
            at += (size_t)rows * (size_t)(m - first);
        }
    }
    double sum = 0.0, total_trace = 0.0;
    for (int j = 0; j < m; j++) {
        sum += block->column_sum[j] * block->weighted_a[j];
        total_trace += block->column_trace[j] * block->q[j];
    }
    *trace = 2.0 * total_trace;
    return 2.0 * sum;
}

/* -- eqs. 1-6 per distinct sample and per distinct sample pair ------------------------------ */

/* Eqs. 1 and 2 of output a's distinct sample t (MomentMatcher.__call__, singles, mean_s,
 * cross_s): u_ati on the uncertain regressors, M_at, ln|I + T_at| and q_at (eq. 1 in the
 * Woodbury form -1/2 nu^T (S + Lambda)^-1 nu = -1/2 nu^T u + 1/2 u^T M_a u), kept in the
 * OutputGP for pair_covariance; E[f_a] = beta_a^T q_a (eq. 1, standardised) in gp->mean[t];
 * Cov[x, f_a] = M_a sum_i u_ai beta_ai q_ai (eq. 2 with S (S + Lambda_a)^-1 nu_i = M_a u_i, zero
 * on the known regressors) added count[t] times to scratch->cross_sum. m: the standardised input mean,
 * S_z the uncertain regressors' covariance. Returns 0 if a Cholesky factor of eq. 6 fails. */
static inline __attribute__((always_inline)) int sample_terms(Model *model, Scratch *scratch, int a, int t,
                                                              const double m[D], const double S_z[N_Z * N_Z]) {
    double *cross_sum = scratch->cross_sum;
    OutputGP *gp = &model->gp[a];
    const size_t n = (size_t)gp->m;
    const double *sample = gp->samples + (size_t)t * gp->sample_size;
    const double *beta = sample, log_signal_variance = sample[n + D];
    const double *precision = gp->precision + (size_t)t * D;
    double *M = gp->M + (size_t)t * N_Z * N_Z, *u_z = gp->uz + (size_t)t * N_Z * n;
    double *q = gp->q + (size_t)t * n, *weighted = gp->weighted + (size_t)t * n;
    if (!woodbury_terms(&scratch->woodbury, precision + KNOWN_REGRESSORS, S_z, M, &gp->log_det[t])) return 0;
    double mean = 0.0, sum_u[N_Z] = {0.0};
    for (size_t i = 0; i < n; i++) { /* q_ai's exponent, then q_ai in a loop that vectorises */
        double nu_u = 0.0;
        for (int c = 0; c < D; c++) {
            const double nu = gp->frame_basis[i * D + c] - m[c], u = nu * precision[c];
            nu_u += nu * u;
            if (c >= KNOWN_REGRESSORS) u_z[(c - KNOWN_REGRESSORS) * n + i] = u;
        }
        q[i] = log_signal_variance - 0.5 * gp->log_det[t] - 0.5 * nu_u + 0.5 * quadratic_form(u_z + i, n, M);
    }
SIMD_LOOP
    for (size_t i = 0; i < n; i++) q[i] = exp_branchless(q[i]);
    for (size_t i = 0; i < n; i++) {
        weighted[i] = beta[i] * q[i];
        mean += weighted[i];
        for (int c = 0; c < N_Z; c++) sum_u[c] += u_z[c * n + i] * weighted[i];
    }
    gp->mean[t] = mean;
    double *products = gp->uu + (size_t)t * N_PRODUCTS * n; /* for pair_covariance's quadratic forms */
    for (int c = 0, k = 0; c < N_Z; c++)
        for (int e = c; e < N_Z; e++, k++)
            for (size_t i = 0; i < n; i++) products[k * n + i] = u_z[c * n + i] * u_z[e * n + i];
    for (int c = 0; c < N_Z; c++) {
        double value = 0.0;
        for (int e = 0; e < N_Z; e++) value += M[c * N_Z + e] * sum_u[e];
        cross_sum[(KNOWN_REGRESSORS + c) * N_OUTPUTS + a] += gp->count[t] * value;
    }
    return 1;
}

/* out_i = 1/2 u_i^T M u_i + constant for n vectors u_i and a symmetric M (N_Z x N_Z), from the
 * products u_i,c u_i,e (c <= e) that sample_terms keeps (products[k * n + i], k counting the
 * pairs c <= e row by row): one pass over i, N_PRODUCTS multiply-adds each. */
static inline __attribute__((always_inline)) void half_quadratic_forms(size_t n, const double *restrict products, const double M[N_Z * N_Z],
                                 double constant, double *restrict out) {
    double factor[N_PRODUCTS];
    for (int c = 0, k = 0; c < N_Z; c++)
        for (int e = c; e < N_Z; e++, k++) factor[k] = (e == c ? 0.5 : 1.0) * M[c * N_Z + e]; /* c < e twice */
    for (size_t i = 0; i < n; i++) {
        double value = constant;
#pragma GCC unroll 64
        for (int k = 0; k < N_PRODUCTS; k++) value += factor[k] * products[k * n + i];
        out[i] = value;
    }
}

/* Eqs. 3-6 of output a's sample t_a with output b's sample t_b (MomentMatcher.__call__, cov_s),
 * from sample_terms' results: Cov[f_a, f_b] = beta_a^T (Q^ab - q_a q_b^T) beta_b with
 * Q^ab_ij - q_ai q_bj = q_ai q_bj expm1(D_ij) (eq. 6), z^T M_ab z expanded over z_ij = u_ai + u_bj;
 * for a == b (then t_a == t_b) plus the expected variance (eq. 4, clipped at zero as
 * GaussianProcess.predict) and the noise (eq. 5). Standardised output units. Returns 0 if a
 * Cholesky factor of eq. 6 fails. */
static inline __attribute__((always_inline)) int pair_covariance(const Model *model, Scratch *scratch, int a, int t_a,
                                                                 int b, int t_b, const double S_z[N_Z * N_Z],
                           double *covariance) {
    const OutputGP *ga = &model->gp[a], *gb = &model->gp[b];
    const size_t ma = (size_t)ga->m, mb = (size_t)gb->m;
    const double *precision_a = ga->precision + (size_t)t_a * D + KNOWN_REGRESSORS;
    const double *precision_b = gb->precision + (size_t)t_b * D + KNOWN_REGRESSORS;
    double precision_ab[N_Z], M_ab[N_Z * N_Z], M_diff[N_Z * N_Z], log_det_ab;
    for (int c = 0; c < N_Z; c++) precision_ab[c] = precision_a[c] + precision_b[c];
    if (!woodbury_terms(&scratch->woodbury, precision_ab, S_z, M_ab, &log_det_ab)) return 0;
    const double constant = -0.5 * (log_det_ab - ga->log_det[t_a] - gb->log_det[t_b]);
    const double *u_a = ga->uz + (size_t)t_a * N_Z * ma, *u_b = gb->uz + (size_t)t_b * N_Z * mb;
    /* half_a_i = 1/2 u_ai^T (M_ab - M_a) u_ai + the constant; half_b_j likewise; u_M = M_ab u_a */
    const double *M_a = ga->M + (size_t)t_a * N_Z * N_Z, *M_b = gb->M + (size_t)t_b * N_Z * N_Z;
    for (int c = 0; c < N_Z * N_Z; c++) M_diff[c] = M_ab[c] - M_a[c];
    half_quadratic_forms(ma, ga->uu + (size_t)t_a * N_PRODUCTS * ma, M_diff, constant, scratch->half_a);
    if (a == b) { /* the same sample: half_b = half_a without the constant */
        for (size_t j = 0; j < mb; j++) scratch->half_b[j] = scratch->half_a[j] - constant;
    } else {
        for (int c = 0; c < N_Z * N_Z; c++) M_diff[c] = M_ab[c] - M_b[c];
        half_quadratic_forms(mb, gb->uu + (size_t)t_b * N_PRODUCTS * mb, M_diff, 0.0, scratch->half_b);
    }
    for (int c = 0; c < N_Z; c++) {
        double *restrict u_M = scratch->u_M + c * ma;
        const double *restrict M_c = M_ab + c * N_Z;
SIMD_LOOP
        for (size_t i = 0; i < ma; i++) {
            double value = 0.0;
            for (int e = 0; e < N_Z; e++) value += M_c[e] * u_a[e * ma + i];
            u_M[i] = value;
        }
    }
    PairBlock block = {(int)ma, (int)mb, scratch->half_a, scratch->half_b, scratch->u_M, u_b,
                       ga->weighted + (size_t)t_a * ma, gb->weighted + (size_t)t_b * mb,
                       ga->K_inv + (size_t)t_a * ma * ma, ga->q + (size_t)t_a * ma, scratch->tile, scratch->tile_single, scratch->columns_single,
                       scratch->column_sum, scratch->column_trace};
    if (a != b) {
        *covariance = model->single_precision ? cross_block_body(&block, 1) : cross_block_body(&block, 0);
        return 1;
    }
    double trace; /* tr(A_t Q^aa) (eq. 4) */
    const double sum = model->single_precision ? own_block_body(&block, &trace, 1) : own_block_body(&block, &trace, 0);
    const double *sample = ga->samples + (size_t)t_a * ga->sample_size;
    const double expected_var = ga->signal_variance[t_a] - trace;
    *covariance = sum + (expected_var > 0.0 ? expected_var : 0.0) + sample[ma + D + 1];
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

/* -- a free-run step on one or two threads ------------------------------------------------ */

#if defined(__x86_64__) && defined(__GNUC__)
#define CPU_RELAX() __builtin_ia32_pause()
#else
#define CPU_RELAX() ((void)0)
#endif

/* Waiting for the other thread: spin (it is usually a few microseconds away), but after
 * SPINS_BEFORE_YIELD turns give the processor up on every turn, so that a thread waiting on a
 * processor that both threads ended up on (the other one busy with another program) does not
 * hold up the thread it waits for. */
#define SPINS_BEFORE_YIELD 2000
static void wait_turn(int *spins) {
    if (++*spins > SPINS_BEFORE_YIELD)
        sched_yield();
    else
        CPU_RELAX();
}

/* The two threads meet between a share's phases (every sample's terms before any pair block):
 * the last to arrive moves the phase on, the other spins until it does. */
static void spin_barrier(Worker *worker) {
    const unsigned phase = __atomic_load_n(&worker->barrier_phase, __ATOMIC_ACQUIRE);
    if (__atomic_add_fetch(&worker->barrier_count, 1, __ATOMIC_ACQ_REL) == THREADS) {
        __atomic_store_n(&worker->barrier_count, 0, __ATOMIC_RELAXED);
        __atomic_store_n(&worker->barrier_phase, phase + 1, __ATOMIC_RELEASE);
    } else {
        int spins = 0;
        while (__atomic_load_n(&worker->barrier_phase, __ATOMIC_ACQUIRE) == phase) wait_turn(&spins);
    }
}

/* Thread k's share of a step (k < model->threads) at the standardised regressor belief
 * (model->step_m, model->step_S_z): eqs. 1-2 of its samples (sample_terms), then, when every
 * thread has done its samples, eqs. 3-6 of its pair blocks (pair_covariance), each added
 * `weight` times to its scratch's cov_sum. With one thread, thread 0 takes every job in the
 * order of the original loops. Sets scratch->samples_failed or ->failed if a Cholesky factor of
 * eq. 6 fails (in its samples or its blocks; the threads read each other's samples_failed only). */
static inline __attribute__((always_inline)) void moment_match_share_body(Model *model, int k) {
    Scratch *scratch = &model->scratch[k];
    const int threads = model->threads;
    const double *m = model->step_m, *S_z = model->step_S_z;
    for (int c = 0; c < N_OUTPUTS * N_OUTPUTS; c++) scratch->cov_sum[c] = 0.0;
    for (int c = 0; c < D * N_OUTPUTS; c++) scratch->cross_sum[c] = 0.0;
    scratch->samples_failed = scratch->failed = 0;
    const int last_share = k + 1 == threads;
    const int last_sample = last_share ? model->n_sample_jobs : model->sample_split[k + 1];
    for (int j = model->sample_split[k]; j < last_sample && !scratch->samples_failed; j++)
        scratch->samples_failed = !sample_terms(model, scratch, model->pair_jobs[j].a, model->pair_jobs[j].t_a, m, S_z);
    if (threads > 1) spin_barrier(&model->worker); /* every thread's samples_failed is final now */
    for (int other = 0; other < threads; other++)
        if (model->scratch[other].samples_failed) return;
    const int last_pair = last_share ? model->n_pair_jobs : model->pair_split[k + 1];
    for (int j = model->pair_split[k]; j < last_pair; j++) {
        const PairJob *job = &model->pair_jobs[j];
        double covariance;
        if (!pair_covariance(model, scratch, job->a, job->t_a, job->b, job->t_b, S_z, &covariance)) {
            scratch->failed = 1;
            return;
        }
        scratch->cov_sum[job->a * N_OUTPUTS + job->b] += job->weight * covariance;
    }
}

/* moment_match_share_body compiled three times, for AVX-512, for AVX2 with FMA and for any
 * x86-64 (everything it calls per sample and per pair block inlined into each), and the widest
 * the processor runs picked once at load (select_moment_match): the FMU stays portable while its
 * loops run 8 or 4 doubles (16 or 8 floats) wide where they can. */
typedef void (*MomentMatchShare)(Model *, int);
#define MOMENT_MATCH_SHARE(suffix, target) \
    target static void moment_match_share_##suffix(Model *model, int k) { moment_match_share_body(model, k); }
#if defined(__x86_64__) && defined(__GNUC__)
MOMENT_MATCH_SHARE(avx512, __attribute__((target("avx512f,avx512dq,avx512vl,avx2,fma"))))
MOMENT_MATCH_SHARE(avx2, __attribute__((target("avx2,fma"))))
#endif
MOMENT_MATCH_SHARE(generic, )

static MomentMatchShare moment_match_share = moment_match_share_generic;

static void select_moment_match(void) {
#if defined(__x86_64__) && defined(__GNUC__)
    __builtin_cpu_init();
    if (__builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512dq")
        && __builtin_cpu_supports("avx512vl"))
        moment_match_share = moment_match_share_avx512;
    else if (__builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma"))
        moment_match_share = moment_match_share_avx2;
#endif
}

/* How long the second thread spins for the next step before it sleeps on the condition
 * variable: a host that steps in a loop (the C host, fmpy) calls again within this, and the
 * thread then starts without a system call; a host stepping in real time finds it asleep. */
#define WORKER_SPIN_NS 200000L

static long elapsed_ns(const struct timespec *since) {
    struct timespec now;
    clock_gettime(CLOCK_MONOTONIC, &now);
    return (now.tv_sec - since->tv_sec) * 1000000000L + (now.tv_nsec - since->tv_nsec);
}

/* The second thread: thread 1's share of every step, until stop_worker. */
static void *worker_main(void *argument) {
    Model *model = argument;
    Worker *worker = &model->worker;
    unsigned seen = 0;
    for (;;) {
        struct timespec spin_start;
        clock_gettime(CLOCK_MONOTONIC, &spin_start);
        unsigned generation;
        for (int spins = 1; (generation = __atomic_load_n(&worker->generation, __ATOMIC_ACQUIRE)) == seen; spins++) {
            if (spins % 64 == 0 && elapsed_ns(&spin_start) > WORKER_SPIN_NS) {
                pthread_mutex_lock(&worker->lock);
                while (worker->generation == seen) pthread_cond_wait(&worker->start, &worker->lock);
                pthread_mutex_unlock(&worker->lock);
            }
            CPU_RELAX();
        }
        if (__atomic_load_n(&worker->quit, __ATOMIC_ACQUIRE)) return NULL;
        seen = generation;
        moment_match_share(model, 1);
        __atomic_store_n(&worker->finished, seen, __ATOMIC_RELEASE);
    }
}

/* Starts the second thread once (the first step with parallel = true); returns 0 if the system
 * refuses it (the step then runs on one thread). */
static int start_worker(Model *model) {
    Worker *worker = &model->worker;
    if (worker->running) return 1;
    if (pthread_mutex_init(&worker->lock, NULL) != 0) return 0;
    if (pthread_cond_init(&worker->start, NULL) != 0) {
        pthread_mutex_destroy(&worker->lock);
        return 0;
    }
    worker->generation = worker->finished = 0;
    worker->quit = 0;
    if (pthread_create(&worker->thread, NULL, worker_main, model) != 0) {
        pthread_cond_destroy(&worker->start);
        pthread_mutex_destroy(&worker->lock);
        return 0;
    }
    worker->running = 1;
    return 1;
}

/* Wakes the second thread for a new generation (a step, or quitting). */
static void wake_worker(Worker *worker) {
    pthread_mutex_lock(&worker->lock);
    __atomic_store_n(&worker->generation, worker->generation + 1, __ATOMIC_RELEASE);
    pthread_cond_signal(&worker->start);
    pthread_mutex_unlock(&worker->lock);
}

static void stop_worker(Model *model) {
    Worker *worker = &model->worker;
    if (!worker->running) return;
    __atomic_store_n(&worker->quit, 1, __ATOMIC_RELEASE);
    wake_worker(worker);
    pthread_join(worker->thread, NULL);
    pthread_cond_destroy(&worker->start);
    pthread_mutex_destroy(&worker->lock);
    worker->running = 0;
}

/* MomentMatcher.__call__ with include_noise = True: the exact mean (N_OUTPUTS), covariance
 * (N_OUTPUTS x N_OUTPUTS, row-major) and input-output cross-covariance (d x N_OUTPUTS) of the
 * mixture over the JOINT_SAMPLES hyperparameter samples (sample s of every output forms model s)
 * at a regressor x ~ N(x_mean, x_cov) (raw units): the input standardised and checked
 * (covariance_problem), then eqs. 1-2 per distinct sample (sample_terms), eqs. 3-6 per distinct
 * sample of each output and per distinct sample pair of each output pair (pair_covariance), each
 * counted as often as the joint samples hold it, on model->threads threads
 * (moment_match_share_body; the second thread's partial sums added to the first's), then the
 * mixture (mixture_moments). Returns 0 and sets *problem (a malloc'd message; NULL if out of
 * memory) if x_cov fails the checks of covariance_problem or a Cholesky factor of eq. 6 fails. */
static int moment_match(Model *model, const double x_mean[D], const double x_cov[D * D], double out_mean[N_OUTPUTS],
                        double out_cov[N_OUTPUTS * N_OUTPUTS], double cross_cov[D * N_OUTPUTS], char **problem) {
    double S[D * D];
    int failed;
    /* MomentMatcher._standardise: into the common frame, checked, S symmetrised */
    *problem = covariance_problem(model, x_mean, x_cov, S, &failed);
    if (failed) return 0;
    for (int i = 0; i < D; i++) model->step_m[i] = (x_mean[i] - model->frame_mean[i]) / model->frame_scale[i];
    for (int i = 0; i < N_Z; i++)
        for (int j = 0; j < N_Z; j++)
            model->step_S_z[i * N_Z + j] = S[(KNOWN_REGRESSORS + i) * D + KNOWN_REGRESSORS + j];
    if (model->threads > 1) wake_worker(&model->worker);
    moment_match_share(model, 0);
    if (model->threads > 1)
        for (int spins = 0; __atomic_load_n(&model->worker.finished, __ATOMIC_ACQUIRE) != model->worker.generation;)
            wait_turn(&spins);
    double cov_sum[N_OUTPUTS * N_OUTPUTS] = {0.0}, cross_sum[D * N_OUTPUTS] = {0.0};
    for (int k = 0; k < model->threads; k++) {
        const Scratch *scratch = &model->scratch[k];
        if (scratch->samples_failed || scratch->failed) {
            *problem = cholesky_failure();
            return 0;
        }
        for (int c = 0; c < N_OUTPUTS * N_OUTPUTS; c++) cov_sum[c] += scratch->cov_sum[c];
        for (int c = 0; c < D * N_OUTPUTS; c++) cross_sum[c] += scratch->cross_sum[c];
    }
    for (int a = 0; a < N_OUTPUTS; a++) /* the pair jobs add to (a, b), a < b, only */
        for (int b = a + 1; b < N_OUTPUTS; b++) cov_sum[b * N_OUTPUTS + a] = cov_sum[a * N_OUTPUTS + b];
    for (int s = 0; s < JOINT_SAMPLES; s++)
        for (int a = 0; a < N_OUTPUTS; a++) {
            const OutputGP *gp = &model->gp[a];
            const int t = (int)model->joint[(size_t)s * N_OUTPUTS + a];
            model->sample_means[(size_t)s * N_OUTPUTS + a] = gp->output_mean + gp->output_scale * gp->mean[t];
        }
    mixture_moments(model, JOINT_SAMPLES, cov_sum, cross_sum, out_mean, out_cov, cross_cov);
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
    model->single_precision = values[EXACT_MOMENTS_VR] == 0.0;
    model->threads = 1;
    if (free_run && values[PARALLEL_VR] != 0.0 && !model->worker.refused) {
        if (start_worker(model)) {
            model->threads = THREADS;
        } else {
            model->worker.refused = 1;
            slave_log(slave, fmi2Warning, "parallel: the system refused a second thread; the free run goes on one");
        }
    }
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
