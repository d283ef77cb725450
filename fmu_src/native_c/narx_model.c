/* GP-NARX rate predictor (Bo105 GP-NARX paper, AHS 74th Forum, 2018) for a native FMU: the
 * same formulas, in the same order where it matters, as fmu_src/_runtime.py (NarxPredictor)
 * and fmu_src/rate_predictor.py (RatePredictor), whose docstrings define the timing, the
 * regressor order, the mixture over hyperparameter samples, the bounds and the envelope.
 *
 * Model constants. The structure (signals, lags, value references, training envelope, array
 * sizes) is compiled in from model_config.h; the GP arrays are read at fmi2Instantiate from
 * resources/DATA_FILE, written by fmu_src/native.py:
 *
 *   8 bytes  "FGPNARX1"
 *   8 bytes  number of doubles that follow (uint64, native byte order)
 *   doubles  per output j (d = N_REGRESSORS, m = BASIS_POINTS[j], S = HYPERPARAMETER_SAMPLES[j]):
 *              input_mean (d), input_scale (d), output_mean, output_scale, basis (m x d),
 *              then per hyperparameter sample s:
 *                weights (m), kernel_weights (d), log_signal_variance, noise_variance,
 *                variance factor V_s by columns: if LOWER_TRIANGULAR[j], column c holds rows
 *                c .. m - 1 only (m (m + 1) / 2 doubles in all), else rows 0 .. m - 1 (m x m).
 *
 * Each instance reads its own copy (no memory shared between instances).
 *
 * Prediction of output j at regressor x (all GP arrays in standardised units):
 *   xs = (x - input_mean) / input_scale
 *   k_s,i = exp(log_signal_variance_s - sum_c w_s,c (xs_c - basis_i,c)^2)
 *   mu_s = k_s . weights_s,  var_s = max(sigma_f,s^2 - |V_s k_s|^2, 0) + noise_variance_s
 *   mean = E_s[mu_s], spread = max(E_s[var_s + mu_s^2] - mean^2, 0)   (law of total variance)
 *   output: mean * output_scale + output_mean, variance spread * output_scale^2.
 * V_s = L_s^-1 is lower triangular for an exact GP (LOWER_TRIANGULAR[j]); it is then stored and
 * multiplied without the zeros above the diagonal (adding 0 k_c changes nothing). The step's
 * cost is dominated by streaming the S variance factors from memory (the paper's model: 1200
 * factors of 32 x 32, 5 MB packed), so halving them halves the time.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "model.h"
#include "model_config.h"

#define DATA_MAGIC "FGPNARX1"
#define SIGNALS (N_INPUTS + N_OUTPUTS)

/* Where the hidden state lives in the model's state array (model.h). */
#define INPUT_HISTORY 0                                /* MAX_LAG x N_INPUTS, row i: i steps ago */
#define OUTPUT_HISTORY (MAX_LAG * N_INPUTS)            /* MAX_LAG x N_OUTPUTS */
#define OUTSIDE_ENVELOPE (MAX_LAG * SIGNALS)           /* 1.0 while outside the envelope */

/* One output's GP (pointers into Model.data). */
typedef struct {
    int m, S, lower_triangular;
    size_t sample_size;                      /* doubles per hyperparameter sample */
    const double *input_mean, *input_scale;  /* (d,) */
    double output_mean, output_scale;
    const double *basis;                     /* (m, d) */
    const double *samples;                   /* S blocks of sample_size doubles */
    double *signal_variance;                 /* (S,) exp(log_signal_variance) */
} OutputGP;


struct Model {
    double *data;
    OutputGP gp[N_OUTPUTS];
    double lower[N_REGRESSORS], upper[N_REGRESSORS];  /* the envelope with its margin */
    double *squared;                                  /* scratch (m_max, d) */
    double *k, *v;                                    /* scratch (m_max,) */
};

void model_free(Model *model) {
    if (model == NULL) return;
    for (int j = 0; j < N_OUTPUTS; j++) free(model->gp[j].signal_variance);
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
    size_t length = strlen(resources_dir);
    const char *separator = length > 0 && resources_dir[length - 1] == '/' ? "" : "/";
    char *path = format_message("%s%s%s", resources_dir, separator, DATA_FILE);
    if (path == NULL) return fail(model, error, NULL);
    FILE *file = fopen(path, "rb");
    char magic[8];
    uint64_t count = 0;
    int ok = file != NULL && fread(magic, 1, 8, file) == 8 && memcmp(magic, DATA_MAGIC, 8) == 0
             && fread(&count, sizeof(count), 1, file) == 1 && count == (uint64_t)DATA_DOUBLES;
    if (ok) {
        model->data = malloc(sizeof(double) * (size_t)DATA_DOUBLES);
        ok = model->data != NULL && fread(model->data, sizeof(double), DATA_DOUBLES, file) == DATA_DOUBLES
             && fgetc(file) == EOF;
    }
    if (file != NULL) fclose(file);
    if (!ok) {
        char *message = format_message("cannot read the model constants %s: missing, truncated or not the "
                                       "%lu doubles this binary was built for (rebuild the FMU)", path,
                                       (unsigned long)DATA_DOUBLES);
        free(path);
        return fail(model, error, message);
    }
    free(path);
    /* Point every output's GP into the data (layout above). */
    const double *p = model->data;
    int m_max = 1;
    for (int j = 0; j < N_OUTPUTS; j++) {
        OutputGP *gp = &model->gp[j];
        gp->m = BASIS_POINTS[j];
        gp->S = HYPERPARAMETER_SAMPLES[j];
        gp->lower_triangular = LOWER_TRIANGULAR[j];
        size_t m = (size_t)gp->m;
        gp->sample_size = m + N_REGRESSORS + 2 + (gp->lower_triangular ? m * (m + 1) / 2 : m * m);
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
    /* Envelope: the training range widened by ENVELOPE_MARGIN of it on each side (_runtime.Envelope). */
    for (int i = 0; i < N_REGRESSORS; i++) {
        double margin = ENVELOPE_MARGIN * (ENVELOPE_HIGH[i] - ENVELOPE_LOW[i]);
        model->lower[i] = ENVELOPE_LOW[i] - margin;
        model->upper[i] = ENVELOPE_HIGH[i] + margin;
    }
    model->squared = malloc(sizeof(double) * (size_t)m_max * N_REGRESSORS);
    model->k = malloc(sizeof(double) * (size_t)m_max);
    model->v = malloc(sizeof(double) * (size_t)m_max);
    if (model->squared == NULL || model->k == NULL || model->v == NULL) return fail(model, error, NULL);
    return model;
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

/* v = V k for a lower triangular V stored by packed columns (column c: rows c .. m - 1). */
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

/* Mean and variance (measurement noise included) of output gp at regressor x (physical
 * units): the mixture over its hyperparameter samples (_runtime._Block.predict). */
static void predict_output(const Model *model, const OutputGP *gp, const double x[N_REGRESSORS],
                           double *mean_out, double *var_out) {
    const int m = gp->m, d = N_REGRESSORS;
    double xs[N_REGRESSORS];
    for (int c = 0; c < d; c++) xs[c] = (x[c] - gp->input_mean[c]) / gp->input_scale[c];
    double *squared = model->squared, *k = model->k, *v = model->v;
    for (int i = 0; i < m; i++)
        for (int c = 0; c < d; c++) {
            double difference = xs[c] - gp->basis[i * d + c];
            squared[i * d + c] = difference * difference;
        }
    double sum_mean = 0.0, sum_second = 0.0;
    for (int s = 0; s < gp->S; s++) {
        const double *sample = gp->samples + (size_t)s * gp->sample_size;
        const double *weights = sample, *kernel_weights = sample + m;
        const double log_signal_variance = sample[m + d], noise_variance = sample[m + d + 1];
        const double *factor = sample + m + d + 2;
        /* kernel vector and mean */
        double mu = 0.0;
        for (int i = 0; i < m; i++) {
            double exponent = 0.0;
            for (int c = 0; c < d; c++) exponent += kernel_weights[c] * squared[i * d + c];
            k[i] = exp(log_signal_variance - exponent);
            mu += k[i] * weights[i];
        }
        if (gp->lower_triangular) lower_triangular_product(factor, k, m, v);
        else full_product(factor, k, m, v);
        double explained = 0.0;
        for (int i = 0; i < m; i++) explained += v[i] * v[i];
        double latent = gp->signal_variance[s] - explained;
        double variance = (latent > 0.0 ? latent : 0.0) + noise_variance;
        sum_mean += mu;
        sum_second += variance + mu * mu;
    }
    double mean = sum_mean / gp->S, second = sum_second / gp->S;
    double spread = second - mean * mean;
    if (!(spread > 0.0)) spread = spread != spread ? spread : 0.0; /* max(., 0), NaN kept */
    *mean_out = mean * gp->output_scale + gp->output_mean;
    *var_out = spread * gp->output_scale * gp->output_scale;
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
    set_outputs(values, y0, zero);
}

/* "[a, b, c]" of n numbers, for messages. */
static char *number_list(const double *numbers, int n) {
    char *text = format_message("[");
    for (int i = 0; i < n && text != NULL; i++) {
        char *longer = format_message("%s%s%.17g", text, i ? ", " : "", numbers[i]);
        free(text);
        text = longer;
    }
    char *closed = text == NULL ? NULL : format_message("%s]", text);
    free(text);
    return closed;
}

char *model_advance(Model *model, const Slave *slave, double *values, double *state, double t, double h) {
    double history[MAX_LAG * SIGNALS + 1]; /* the pushed input and output histories */
    double *inputs = history + INPUT_HISTORY, *outputs = history + OUTPUT_HISTORY;
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
    for (int j = 0; j < N_OUTPUTS; j++) {
        predict_output(model, &model->gp[j], x, &mean[j], &var[j]);
        finite = finite && isfinite(mean[j]) && isfinite(var[j]);
    }
    if (!finite) {
        char *m = number_list(mean, N_OUTPUTS), *v = number_list(var, N_OUTPUTS), *r = number_list(x, N_REGRESSORS);
        char *message = format_message("non-finite prediction %s (variance %s) at regressor %s", m ? m : "?",
                                       v ? v : "?", r ? r : "?");
        free(m), free(v), free(r);
        return message != NULL ? message : format_message("non-finite prediction");
    }
    /* Envelope (RatePredictor.advance_model, FlightgpSlave.report_envelope): warn once per excursion. */
    char *outside = NULL;
    for (int i = 0; i < N_REGRESSORS; i++)
        if (x[i] < model->lower[i] || x[i] > model->upper[i]) {
            char *phrase = format_message("%s = %.6g (trained on %.6g .. %.6g)", REGRESSOR_NAMES[i], x[i],
                                          ENVELOPE_LOW[i], ENVELOPE_HIGH[i]);
            char *joined = outside == NULL ? phrase : format_message("%s; %s", outside, phrase ? phrase : "?");
            if (joined != phrase) free(phrase);
            free(outside);
            outside = joined != NULL ? joined : format_message("(out of memory)");
        }
    const int was_outside = state[OUTSIDE_ENVELOPE] != 0.0;
    if (outside != NULL && !was_outside)
        slave_log(slave, fmi2Warning, "t = %.16g s: input outside the training envelope: %s. The GP extrapolates; "
                  "its variance, and so the bounds, widen.", t + h, outside);
    else if (outside == NULL && was_outside)
        slave_log(slave, fmi2OK, "t = %.16g s: back inside the training envelope", t + h);
    /* Commit only after everything that can fail. */
    memcpy(state, history, sizeof(double) * MAX_LAG * SIGNALS);
    state[OUTSIDE_ENVELOPE] = outside != NULL ? 1.0 : 0.0;
    free(outside);
    set_outputs(values, mean, var);
    return NULL;
}
