/* FMI 2.0 co-simulation interface of a flightgp native FMU: the call-sequence state machine,
 * the variable table, logging, the status policy and FMU state save/restore/serialisation.
 * The model (model.h) supplies the equations; model_config.h (generated per FMU by the model's
 * native builder, fmu_src/<model>/native.py) the identity, the variable table and the structure.
 *
 * References are to the FMI 2.0.4 specification (Modelica Association, 2022):
 *   2.1.5  logging (the logger's message is a printf format; we pass "%s" and the text),
 *   2.1.6  creation, destruction and logging of instances (fmi2Instantiate, fmi2FreeInstance,
 *          fmi2SetDebugLogging),
 *   2.1.7  initialisation, termination and resetting (fmi2SetupExperiment,
 *          fmi2Enter/ExitInitializationMode, fmi2Terminate, fmi2Reset),
 *   2.1.8  getting and setting variable values,
 *   2.1.9  getting and setting the complete FMU state (fmi2Get/Set/FreeFMUstate,
 *          fmi2SerializedFMUstateSize, fmi2SerializeFMUstate, fmi2DeSerializeFMUstate),
 *   4.2.2  computation (fmi2DoStep), 4.2.3 retrieving the slave status,
 *   4.2.4  the state machine of calling sequences (which function is legal in which state).
 *
 * Status policy (the same as the pythonfmu FMUs, fmu_src/fmi/slave.py):
 *   - A function called in a state where FMI 2.0 does not allow it returns fmi2Error with a
 *     logged message naming the state; the instance stays in its state.
 *   - Setters store values and check them at the next fmi2DoStep. Setting an output, a fixed
 *     parameter after initialisation or an unknown value reference is refused: the old value
 *     is kept, an Error is logged, the setter returns fmi2Warning, and the next fmi2DoStep
 *     returns fmi2Discard.
 *   - fmi2DoStep refuses (logged Error, fmi2Discard, state and outputs unchanged, so the host
 *     may fix the cause and retry the same step) a NaN, infinite or out-of-range input or
 *     parameter, a wrong step size or communication point, a value refused since the last
 *     step, or a step the model cannot take. The instance stays in stepComplete so that the
 *     retry is legal (FMI 2.0 would move to stepFailed, from which a retry is not).
 *   - fmi2ExitInitializationMode with bad inputs logs an Error and returns fmi2Error (state
 *     error: only fmi2Reset, fmi2FreeInstance and getters are then legal).
 *   - Nothing returns fmi2Fatal. Errors are logged whether or not the host enabled logging;
 *     other messages only for the categories the host enabled.
 *
 * Each instance owns all of its data (its model constants included); there is no mutable
 * global state, so instances in one process are independent.
 */
#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "model.h"
#include "model_config.h"

/* States of FMI 2.0.4, 4.2.4, as bits so that each function lists where it is legal. */
typedef enum {
    MODE_INSTANTIATED = 1 << 0,
    MODE_INITIALIZATION = 1 << 1,
    MODE_STEP_COMPLETE = 1 << 2,
    MODE_TERMINATED = 1 << 3,
    MODE_ERROR = 1 << 4
} Mode;

#define ALL_MODES (MODE_INSTANTIATED | MODE_INITIALIZATION | MODE_STEP_COMPLETE | MODE_TERMINATED | MODE_ERROR)
/* Legal states per function (FMI 2.0.4, 4.2.4; the table of the co-simulation state machine). */
#define MASK_SETUP_EXPERIMENT MODE_INSTANTIATED
#define MASK_ENTER_INITIALIZATION MODE_INSTANTIATED
#define MASK_EXIT_INITIALIZATION MODE_INITIALIZATION
/* FMI 2.0 allows fmi2Terminate after initialisation only; hosts (fmpy's included) also end an
   instance that was never initialised or that failed, so those are accepted as well. */
#define MASK_TERMINATE (MODE_INSTANTIATED | MODE_STEP_COMPLETE | MODE_ERROR)
#define MASK_GET (MODE_INITIALIZATION | MODE_STEP_COMPLETE | MODE_TERMINATED | MODE_ERROR)
#define MASK_SET (MODE_INSTANTIATED | MODE_INITIALIZATION | MODE_STEP_COMPLETE)
#define MASK_FMU_STATE (MODE_INSTANTIATED | MODE_INITIALIZATION | MODE_STEP_COMPLETE | MODE_TERMINATED)
#define MASK_DO_STEP MODE_STEP_COMPLETE
#define MASK_STATUS (MODE_STEP_COMPLETE | MODE_TERMINATED)

#define STATE_SLOTS (MODEL_STATE_SIZE > 0 ? MODEL_STATE_SIZE : 1)

/* The communication step (fmu_src/fmi/slave.py, "Sampling convention"): STEP_SIZE if positive (the
 * model's own step, e.g. the NARX step); if STEP_SIZE is 0, the step of the first fmi2DoStep
 * after initialisation, which must lie in MIN_STEP_SIZE .. MAX_STEP_SIZE (STEP_RANGE_REASON says
 * why; FlightgpSlave.step_problem) and is then kept until fmi2Reset. A model_config.h with a
 * fixed step need not define the range. */
#ifndef MIN_STEP_SIZE
#define MIN_STEP_SIZE STEP_SIZE
#define MAX_STEP_SIZE STEP_SIZE
#define STEP_RANGE_REASON "the model step"
#endif

/* Everything that changes while an instance runs: what fmi2GetFMUstate saves (with the
 * refused-setter message, kept beside it because it is a string). Plain data, no pointers. */
typedef struct {
    int mode;
    double start_time;                 /* t0, s */
    long long step_count;              /* k: the next communication point is t0 + k h */
    double step_size;                  /* h, s; 0 until the first fmi2DoStep fixes it */
    double values[N_VARIABLES];        /* by value reference; Booleans as 0.0 / 1.0 */
    double model_state[STATE_SLOTS];   /* the model's hidden state (model.h) */
} SlaveState;

/* Log categories (declared in modelDescription.xml), by the status they carry. */
static const char *const CATEGORIES[] = {"logAll", "logStatusWarning", "logStatusDiscard",
                                         "logStatusError", "logStatusFatal"};
#define N_CATEGORIES (sizeof(CATEGORIES) / sizeof(CATEGORIES[0]))

struct Slave {
    fmi2CallbackFunctions callbacks;   /* a copy: the host's logger and environment */
    char *instance_name;
    int category_on[N_CATEGORIES];
    Model *model;                      /* constants and scratch, loaded at fmi2Instantiate */
    SlaveState state;
    char *refused;                     /* message of a setter refused since the last step */
};

/* A saved FMU state (fmi2FMUstate points to one). */
#define STATE_MAGIC "flightgp-native-fmu-state-1"
typedef struct {
    char magic[sizeof(STATE_MAGIC)];
    SlaveState state;
    char *refused;
} SavedState;

/* -- strings and logging --------------------------------------------------------------------- */
static char *vformat(const char *format, va_list args) {
    va_list copy;
    va_copy(copy, args);
    int length = vsnprintf(NULL, 0, format, copy);
    va_end(copy);
    if (length < 0) return NULL;
    char *text = malloc((size_t)length + 1);
    if (text != NULL) vsnprintf(text, (size_t)length + 1, format, args);
    return text;
}

char *format_message(const char *format, ...) {
    va_list args;
    va_start(args, format);
    char *text = vformat(format, args);
    va_end(args);
    return text;
}

double *read_model_data(const char *resources_dir, const char *magic, size_t count, char **error) {
    *error = NULL;
    size_t length = strlen(resources_dir);
    const char *separator = length > 0 && resources_dir[length - 1] == '/' ? "" : "/";
    char *path = format_message("%s%s%s", resources_dir, separator, DATA_FILE);
    if (path == NULL) return NULL;
    FILE *file = fopen(path, "rb");
    char found[8];
    uint64_t stored = 0;
    double *data = NULL;
    int ok = file != NULL && fread(found, 1, 8, file) == 8 && memcmp(found, magic, 8) == 0
             && fread(&stored, sizeof(stored), 1, file) == 1 && stored == (uint64_t)count;
    if (ok) {
        data = malloc(sizeof(double) * count);
        ok = data != NULL && fread(data, sizeof(double), count, file) == count && fgetc(file) == EOF;
    }
    if (file != NULL) fclose(file);
    if (!ok) {
        free(data);
        data = NULL;
        *error = format_message("cannot read the model constants %s: missing, truncated or not the %lu doubles "
                                "this binary was built for (rebuild the FMU)", path, (unsigned long)count);
    }
    free(path);
    return data;
}

char *number_list(const double *numbers, int n) {
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

/* The inputs of x outside the envelope as "name = x (trained on a .. b); ..." (malloc'd), or NULL
 * when all are inside. */
static char *envelope_excursions(const double *x, int n, const char *const names[], const double *low,
                                 const double *high, double margin) {
    char *outside = NULL;
    for (int i = 0; i < n; i++) {
        double widen = margin * (high[i] - low[i]);
        if (!(x[i] < low[i] - widen || x[i] > high[i] + widen)) continue;
        char *phrase = format_message("%s = %.6g (trained on %.6g .. %.6g)", names[i], x[i], low[i], high[i]);
        char *joined = outside == NULL ? phrase : format_message("%s; %s", outside, phrase ? phrase : "?");
        if (joined != phrase) free(phrase);
        free(outside);
        outside = joined != NULL ? joined : format_message("(out of memory)");
    }
    return outside;
}

static char *copy_string(const char *text) {
    return text == NULL ? NULL : format_message("%s", text);
}

/* Append separator + formatted text to *text (which may be NULL); keeps *text on failure. */
static void append(char **text, const char *separator, const char *format, ...) {
    va_list args;
    va_start(args, format);
    char *addition = vformat(format, args);
    va_end(args);
    if (addition == NULL) return;
    char *joined = *text == NULL ? copy_string(addition)
                                 : format_message("%s%s%s", *text, separator, addition);
    free(addition);
    if (joined != NULL) {
        free(*text);
        *text = joined;
    }
}

static size_t category_of(fmi2Status status) {
    switch (status) {
        case fmi2Warning: return 1;
        case fmi2Discard: return 2;
        case fmi2Error: return 3;
        case fmi2Fatal: return 4;
        default: return 0;
    }
}

static void log_text(const Slave *slave, fmi2Status status, const char *text) {
    size_t category = category_of(status);
    int on = status >= fmi2Error || slave->category_on[category] || slave->category_on[0];
    if (!on || slave->callbacks.logger == NULL) return;
    /* FMI 2.0.4, 2.1.5: the message is a printf format; "%s" passes the text verbatim. */
    slave->callbacks.logger(slave->callbacks.componentEnvironment, slave->instance_name, status,
                            CATEGORIES[category], "%s", text == NULL ? "(out of memory formatting a message)" : text);
}

void slave_log(const Slave *slave, fmi2Status status, const char *format, ...) {
    va_list args;
    va_start(args, format);
    char *text = vformat(format, args);
    va_end(args);
    log_text(slave, status, text);
    free(text);
}

int report_envelope(const Slave *slave, const double *x, int n, const char *const names[], const double *low,
                    const double *high, double margin, int was_outside, double t, const char *consequence) {
    char *outside = envelope_excursions(x, n, names, low, high, margin);
    if (outside != NULL && !was_outside)
        slave_log(slave, fmi2Warning, "t = %.16g s: input outside the training envelope: %s. The GP extrapolates; %s.",
                  t, outside, consequence);
    else if (outside == NULL && was_outside)
        slave_log(slave, fmi2OK, "t = %.16g s: back inside the training envelope", t);
    const int now_outside = outside != NULL;
    free(outside);
    return now_outside;
}

static const char *mode_name(int mode) {
    switch (mode) {
        case MODE_INSTANTIATED: return "instantiated";
        case MODE_INITIALIZATION: return "initializationMode";
        case MODE_STEP_COMPLETE: return "stepComplete";
        case MODE_TERMINATED: return "terminated";
        default: return "error";
    }
}

/* FMI 2.0.4, 4.2.4: is `function` legal in the instance's state? Logs an Error if not. */
static int legal(const Slave *slave, const char *function, int mask) {
    if (slave->state.mode & mask) return 1;
    slave_log(slave, fmi2Error, "%s: illegal call in the %s state (FMI 2.0 co-simulation call "
              "sequence: fmi2Instantiate, fmi2SetupExperiment, fmi2EnterInitializationMode, "
              "fmi2ExitInitializationMode, fmi2DoStep..., fmi2Terminate; fmi2Reset to start again)",
              function, mode_name(slave->state.mode));
    return 0;
}

/* A setter's refusal: logged now, reported by the next fmi2DoStep as fmi2Discard. */
static fmi2Status refuse(Slave *slave, char *message) {
    log_text(slave, fmi2Error, message);
    free(slave->refused);
    slave->refused = message != NULL ? message : copy_string("a value was refused");
    return fmi2Warning;
}

/* -- instance lifecycle ---------------------------------------------------------------------- */
static void set_start_values(Slave *slave) {
    memset(&slave->state, 0, sizeof(slave->state));
    slave->state.mode = MODE_INSTANTIATED;
    for (size_t vr = 0; vr < N_VARIABLES; vr++) slave->state.values[vr] = VARIABLES[vr].start;
    free(slave->refused);
    slave->refused = NULL;
}

/* The local path of a file: URI (RFC 8089: file:///path, file://localhost/path, file:/path),
 * percent-decoded; NULL if the URI is not such a URI. */
static char *uri_to_path(const char *uri) {
    const char *path;
    if (uri == NULL || strncmp(uri, "file:", 5) != 0) return NULL;
    path = uri + 5;
    if (strncmp(path, "//localhost/", 12) == 0) path += 11;
    else if (strncmp(path, "///", 3) == 0) path += 2;
    else if (strncmp(path, "//", 2) == 0) return NULL; /* a remote host */
    char *decoded = malloc(strlen(path) + 1);
    if (decoded == NULL) return NULL;
    size_t n = 0;
    for (const char *p = path; *p != '\0'; p++) {
        unsigned int byte;
        if (p[0] == '%' && p[1] != '\0' && p[2] != '\0' && sscanf(p + 1, "%2x", &byte) == 1) {
            decoded[n++] = (char)byte;
            p += 2;
        } else {
            decoded[n++] = *p;
        }
    }
    decoded[n] = '\0';
    return decoded;
}

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    (void)visible;
    Slave *slave = calloc(1, sizeof(Slave));
    if (slave == NULL) return NULL;
    if (functions != NULL) slave->callbacks = *functions;
    slave->instance_name = copy_string(instanceName == NULL ? "" : instanceName);
    for (size_t i = 0; i < N_CATEGORIES; i++) slave->category_on[i] = loggingOn;
    set_start_values(slave);
    char *error = NULL;
    if (slave->instance_name == NULL) {
        error = NULL;
    } else if (fmuType != fmi2CoSimulation) {
        error = format_message("fmi2Instantiate: %s is a co-simulation FMU; model exchange is not "
                               "supported", MODEL_IDENTIFIER);
    } else if (fmuGUID == NULL || strcmp(fmuGUID, MODEL_GUID) != 0) {
        error = format_message("fmi2Instantiate: GUID %s does not match this binary's %s (a "
                               "modelDescription.xml of another build?)", fmuGUID ? fmuGUID : "(null)",
                               MODEL_GUID);
    } else {
        char *resources = uri_to_path(fmuResourceLocation);
        if (resources == NULL) {
            error = format_message("fmi2Instantiate: fmuResourceLocation %s is not a local file: URI; "
                                   "the model constants are read from the FMU's resources folder",
                                   fmuResourceLocation ? fmuResourceLocation : "(null)");
        } else {
            slave->model = model_load(resources, &error);
            free(resources);
        }
    }
    if (slave->model == NULL) {
        log_text(slave, fmi2Error, error != NULL ? error : "fmi2Instantiate: out of memory");
        free(error);
        fmi2FreeInstance(slave);
        return NULL;
    }
    return slave;
}

void fmi2FreeInstance(fmi2Component c) {
    Slave *slave = c;
    if (slave == NULL) return;
    model_free(slave->model);
    free(slave->refused);
    free(slave->instance_name);
    free(slave);
}

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    Slave *slave = c;
    if (!legal(slave, "fmi2SetDebugLogging", ALL_MODES)) return fmi2Error;
    if (nCategories == 0) {
        for (size_t i = 0; i < N_CATEGORIES; i++) slave->category_on[i] = loggingOn;
        return fmi2OK;
    }
    fmi2Status status = fmi2OK;
    for (size_t k = 0; k < nCategories; k++) {
        size_t i = 0;
        while (i < N_CATEGORIES && (categories[k] == NULL || strcmp(categories[k], CATEGORIES[i]) != 0)) i++;
        if (i == N_CATEGORIES) {
            slave_log(slave, fmi2Error, "fmi2SetDebugLogging: unknown log category %s (known: logAll, "
                      "logStatusWarning, logStatusDiscard, logStatusError, logStatusFatal)",
                      categories[k] ? categories[k] : "(null)");
            status = fmi2Error;
        } else {
            slave->category_on[i] = loggingOn;
        }
    }
    return status;
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    Slave *slave = c;
    (void)toleranceDefined, (void)tolerance, (void)stopTimeDefined, (void)stopTime;
    if (!legal(slave, "fmi2SetupExperiment", MASK_SETUP_EXPERIMENT)) return fmi2Error;
    if (!isfinite(startTime)) {
        slave_log(slave, fmi2Error, "fmi2SetupExperiment: startTime = %g is not a finite number", startTime);
        return fmi2Error;
    }
    slave->state.start_time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    Slave *slave = c;
    if (!legal(slave, "fmi2EnterInitializationMode", MASK_ENTER_INITIALIZATION)) return fmi2Error;
    slave->state.mode = MODE_INITIALIZATION;
    return fmi2OK;
}

/* Problems of the current input and parameter values (NaN, inf, outside min/max), joined by
 * "; ", or NULL if none (the messages of fmu_src/fmi/slave.py, Variable.problem). */
static char *input_problems(const Slave *slave) {
    char *problems = NULL;
    for (size_t vr = 0; vr < N_VARIABLES; vr++) {
        const VariableInfo *v = &VARIABLES[vr];
        double value = slave->state.values[vr];
        if (v->causality == CAUSALITY_OUTPUT || v->kind != KIND_REAL) continue;
        if (v->minimum <= value && value <= v->maximum) continue; /* NaN fails both */
        if (!isfinite(value))
            append(&problems, "; ", "%s = %g is not a finite number", v->name, value);
        else if (value < v->minimum)
            append(&problems, "; ", "%s = %.16g is below its minimum %.16g [%s]", v->name, value, v->minimum, v->unit);
        else
            append(&problems, "; ", "%s = %.16g is above its maximum %.16g [%s]", v->name, value, v->maximum, v->unit);
    }
    return problems;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    Slave *slave = c;
    if (!legal(slave, "fmi2ExitInitializationMode", MASK_EXIT_INITIALIZATION)) return fmi2Error;
    char *problems = input_problems(slave);
    if (problems != NULL) {
        slave_log(slave, fmi2Error, "initialisation refused (fmi2Error; fix the values, then fmi2Reset): %s",
                  problems);
        free(problems);
        slave->state.mode = MODE_ERROR;
        return fmi2Error;
    }
    slave->state.step_count = 0;
    slave->state.step_size = STEP_SIZE;
    free(slave->refused);
    slave->refused = NULL;
    model_start(slave->model, slave->state.values, slave->state.model_state);
    slave->state.mode = MODE_STEP_COMPLETE;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    Slave *slave = c;
    if (!legal(slave, "fmi2Terminate", MASK_TERMINATE)) return fmi2Error;
    slave->state.mode = MODE_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    Slave *slave = c;
    if (!legal(slave, "fmi2Reset", ALL_MODES)) return fmi2Error;
    set_start_values(slave);
    return fmi2OK;
}

/* -- variable values (FMI 2.0.4, 2.1.8) ------------------------------------------------------ */
static int has_kind(fmi2ValueReference vr, int kind) {
    return vr < N_VARIABLES && VARIABLES[vr].kind == kind;
}

/* One value by reference: the value, or (logged Error) NaN / false for an unknown reference. */
static fmi2Status get_value(const Slave *slave, const char *function, int kind, fmi2ValueReference vr,
                            double *out) {
    if (has_kind(vr, kind)) {
        *out = slave->state.values[vr];
        return fmi2OK;
    }
    slave_log(slave, fmi2Error, "%s: value reference %u is not a %s variable of this FMU", function,
              (unsigned)vr, kind == KIND_REAL ? "Real" : "Boolean");
    *out = kind == KIND_REAL ? NAN : 0.0;
    return fmi2Error;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    Slave *slave = c;
    if (!legal(slave, "fmi2GetReal", MASK_GET)) return fmi2Error;
    fmi2Status status = fmi2OK;
    for (size_t i = 0; i < nvr; i++) {
        fmi2Status one = get_value(slave, "fmi2GetReal", KIND_REAL, vr[i], &value[i]);
        if (one > status) status = one;
    }
    return status;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[]) {
    Slave *slave = c;
    if (!legal(slave, "fmi2GetBoolean", MASK_GET)) return fmi2Error;
    fmi2Status status = fmi2OK;
    for (size_t i = 0; i < nvr; i++) {
        double number;
        fmi2Status one = get_value(slave, "fmi2GetBoolean", KIND_BOOLEAN, vr[i], &number);
        value[i] = number != 0.0 ? fmi2True : fmi2False;
        if (one > status) status = one;
    }
    return status;
}

/* This FMU has no Integer or String variables: any value reference is unknown. */
static fmi2Status no_such_values(Slave *slave, const char *function, const char *kind, size_t nvr, int set) {
    if (!legal(slave, function, set ? MASK_SET : MASK_GET)) return fmi2Error;
    if (nvr == 0) return fmi2OK;
    char *message = format_message("%s: this FMU has no %s variables (%u value references given)", function,
                                   kind, (unsigned)nvr);
    if (set) return refuse(slave, message);
    log_text(slave, fmi2Error, message);
    free(message);
    return fmi2Error;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]) {
    (void)vr, (void)value;
    return no_such_values(c, "fmi2GetInteger", "Integer", nvr, 0);
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) {
    (void)vr, (void)value;
    return no_such_values(c, "fmi2GetString", "String", nvr, 0);
}

/* Store one value (checked for range and finiteness at the next step), or refuse it. */
static fmi2Status set_value(Slave *slave, const char *function, int kind, fmi2ValueReference vr, double value) {
    if (!has_kind(vr, kind))
        return refuse(slave, format_message("%s: value reference %u is not a %s variable of this FMU", function,
                                            (unsigned)vr, kind == KIND_REAL ? "Real" : "Boolean"));
    const VariableInfo *v = &VARIABLES[vr];
    if (v->causality == CAUSALITY_OUTPUT)
        return refuse(slave, format_message("%s is an output; it cannot be set", v->name));
    if (v->variability == VARIABILITY_FIXED && !(slave->state.mode & (MODE_INSTANTIATED | MODE_INITIALIZATION)))
        return refuse(slave, format_message("%s is a fixed parameter; it can only be set before the end of "
                                            "initialisation (kept %.17g)", v->name, slave->state.values[vr]));
    slave->state.values[vr] = value;
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    Slave *slave = c;
    if (!legal(slave, "fmi2SetReal", MASK_SET)) return fmi2Error;
    fmi2Status status = fmi2OK;
    for (size_t i = 0; i < nvr; i++) {
        fmi2Status one = set_value(slave, "fmi2SetReal", KIND_REAL, vr[i], value[i]);
        if (one > status) status = one;
    }
    return status;
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[]) {
    Slave *slave = c;
    if (!legal(slave, "fmi2SetBoolean", MASK_SET)) return fmi2Error;
    fmi2Status status = fmi2OK;
    for (size_t i = 0; i < nvr; i++) {
        fmi2Status one = set_value(slave, "fmi2SetBoolean", KIND_BOOLEAN, vr[i], value[i] ? 1.0 : 0.0);
        if (one > status) status = one;
    }
    return status;
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[]) {
    (void)vr, (void)value;
    return no_such_values(c, "fmi2SetInteger", "Integer", nvr, 1);
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[]) {
    (void)vr, (void)value;
    return no_such_values(c, "fmi2SetString", "String", nvr, 1);
}

/* -- computation (FMI 2.0.4, 4.2.2) ---------------------------------------------------------- */
/* Why fmi2DoStep(t, h) cannot be taken now, or NULL (the order and the messages of
 * fmu_src/fmi/slave.py, FlightgpSlave._step_refusal); *step is set to the step to take. */
static char *step_refusal(Slave *slave, double t, double h, double *step) {
    if (slave->refused != NULL) {
        char *message = format_message("a value was refused since the last step: %s", slave->refused);
        free(slave->refused);
        slave->refused = NULL;
        return message;
    }
    char *problems = input_problems(slave);
    if (problems != NULL) return problems;
    *step = slave->state.step_size;
    if (*step == 0.0) { /* the first step fixes the step */
        if (!(h > 0.0)) return format_message("communicationStepSize must be positive, got %.16g", h);
        if (!(MIN_STEP_SIZE <= h && h <= MAX_STEP_SIZE))
            return format_message("communicationStepSize %.16g s is outside %.6g .. %.6g s, %s", h, MIN_STEP_SIZE,
                                  MAX_STEP_SIZE, STEP_RANGE_REASON);
        *step = h;
    } else if (!(fabs(h - *step) <= TIME_TOLERANCE * *step)) {
        return format_message("expected communicationStepSize = %.16g s but was %.16g s (this FMU advances in "
                              "steps of exactly %s)", *step, h,
                              STEP_SIZE > 0.0 ? "its model step" : "the step of its first fmi2DoStep, until reset");
    }
    double expected = slave->state.start_time + (double)slave->state.step_count * *step;
    if (!(fabs(t - expected) <= TIME_TOLERANCE * *step))
        return format_message("expected currentCommunicationPoint = %.16g s but was %.16g s", expected, t);
    return NULL;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    Slave *slave = c;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!legal(slave, "fmi2DoStep", MASK_DO_STEP)) return fmi2Error;
    double step = 0.0;
    char *refusal = step_refusal(slave, currentCommunicationPoint, communicationStepSize, &step);
    if (refusal == NULL)
        refusal = model_advance(slave->model, slave, slave->state.values, slave->state.model_state,
                                currentCommunicationPoint, step);
    if (refusal != NULL) {
        slave_log(slave, fmi2Error, "fmi2DoStep at t = %.16g s refused (fmi2Discard): %s",
                  currentCommunicationPoint, refusal);
        free(refusal);
        return fmi2Discard;
    }
    slave->state.step_size = step;
    slave->state.step_count++;
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    slave_log(c, fmi2Error, "fmi2CancelStep: fmi2DoStep never returns fmi2Pending in this FMU");
    return fmi2Error;
}

/* FMI 2.0.4, 4.2.3: the only status this FMU provides is the last successful time. */
fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    (void)value;
    slave_log(c, fmi2Error, "fmi2GetStatus: status kind %d is not provided (fmi2DoStep is never pending)", (int)s);
    return fmi2Discard;
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    Slave *slave = c;
    if (!legal(slave, "fmi2GetRealStatus", MASK_STATUS)) return fmi2Error;
    if (s != fmi2LastSuccessfulTime) {
        slave_log(slave, fmi2Error, "fmi2GetRealStatus: status kind %d is not provided", (int)s);
        return fmi2Discard;
    }
    *value = slave->state.start_time + (double)slave->state.step_count * slave->state.step_size;
    return fmi2OK;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    (void)value;
    slave_log(c, fmi2Error, "fmi2GetIntegerStatus: status kind %d is not provided", (int)s);
    return fmi2Discard;
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    Slave *slave = c;
    if (!legal(slave, "fmi2GetBooleanStatus", MASK_STATUS)) return fmi2Error;
    if (s != fmi2Terminated) {
        slave_log(slave, fmi2Error, "fmi2GetBooleanStatus: status kind %d is not provided", (int)s);
        return fmi2Discard;
    }
    *value = fmi2False; /* the FMU never asks to end the simulation */
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    (void)value;
    slave_log(c, fmi2Error, "fmi2GetStringStatus: status kind %d is not provided", (int)s);
    return fmi2Discard;
}

/* Not provided (modelDescription.xml: providesDirectionalDerivative, canInterpolateInputs and
 * maxOutputDerivativeOrder are false / 0). */
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[]) {
    (void)vUnknown_ref, (void)nUnknown, (void)vKnown_ref, (void)nKnown, (void)dvKnown, (void)dvUnknown;
    slave_log(c, fmi2Error, "fmi2GetDirectionalDerivative: not provided by this FMU");
    return fmi2Error;
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr, (void)nvr, (void)order, (void)value;
    slave_log(c, fmi2Error, "fmi2SetRealInputDerivatives: this FMU cannot interpolate inputs");
    return fmi2Error;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr, (void)nvr, (void)order, (void)value;
    slave_log(c, fmi2Error, "fmi2GetRealOutputDerivatives: this FMU provides no output derivatives");
    return fmi2Error;
}

/* -- FMU state (FMI 2.0.4, 2.1.9) ------------------------------------------------------------ */
static SavedState *saved_state(const Slave *slave, const char *function, fmi2FMUstate pointer) {
    SavedState *saved = pointer;
    if (saved == NULL || memcmp(saved->magic, STATE_MAGIC, sizeof(STATE_MAGIC)) != 0) {
        slave_log(slave, fmi2Error, "%s: not an FMU state saved by this FMU", function);
        return NULL;
    }
    return saved;
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    Slave *slave = c;
    if (!legal(slave, "fmi2GetFMUstate", MASK_FMU_STATE)) return fmi2Error;
    SavedState *saved = *FMUstate; /* non-NULL: a state saved before, to overwrite */
    if (saved != NULL && saved_state(slave, "fmi2GetFMUstate", saved) == NULL) return fmi2Error;
    if (saved == NULL && (saved = calloc(1, sizeof(SavedState))) == NULL) {
        slave_log(slave, fmi2Error, "fmi2GetFMUstate: out of memory");
        return fmi2Error;
    }
    memcpy(saved->magic, STATE_MAGIC, sizeof(STATE_MAGIC));
    saved->state = slave->state;
    free(saved->refused);
    saved->refused = copy_string(slave->refused);
    *FMUstate = saved;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    Slave *slave = c;
    if (!legal(slave, "fmi2SetFMUstate", MASK_FMU_STATE)) return fmi2Error;
    const SavedState *saved = saved_state(slave, "fmi2SetFMUstate", FMUstate);
    if (saved == NULL) return fmi2Error;
    slave->state = saved->state;
    free(slave->refused);
    slave->refused = copy_string(saved->refused);
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    Slave *slave = c;
    if (FMUstate == NULL || *FMUstate == NULL) return fmi2OK;
    SavedState *saved = saved_state(slave, "fmi2FreeFMUstate", *FMUstate);
    if (saved == NULL) return fmi2Error;
    free(saved->refused);
    free(saved);
    *FMUstate = NULL;
    return fmi2OK;
}

/* Serialised layout: STATE_MAGIC and MODEL_GUID (each with its NUL), the byte size of a
 * SlaveState (uint64), the SlaveState's bytes, the length of the refused message including
 * its NUL (uint64; 0: none) and the message. Native byte order and layout: a serialised state
 * is read back by the same FMU binary (the GUID and the size guard against others). */
#define HEADER_SIZE (sizeof(STATE_MAGIC) + sizeof(MODEL_GUID) + sizeof(uint64_t))

static size_t serialized_size(const SavedState *saved) {
    size_t message = saved->refused == NULL ? 0 : strlen(saved->refused) + 1;
    return HEADER_SIZE + sizeof(SlaveState) + sizeof(uint64_t) + message;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    Slave *slave = c;
    if (!legal(slave, "fmi2SerializedFMUstateSize", MASK_FMU_STATE)) return fmi2Error;
    const SavedState *saved = saved_state(slave, "fmi2SerializedFMUstateSize", FMUstate);
    if (saved == NULL) return fmi2Error;
    *size = serialized_size(saved);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[], size_t size) {
    Slave *slave = c;
    if (!legal(slave, "fmi2SerializeFMUstate", MASK_FMU_STATE)) return fmi2Error;
    const SavedState *saved = saved_state(slave, "fmi2SerializeFMUstate", FMUstate);
    if (saved == NULL) return fmi2Error;
    if (size != serialized_size(saved)) {
        slave_log(slave, fmi2Error, "fmi2SerializeFMUstate: size = %lu bytes, expected %lu "
                  "(fmi2SerializedFMUstateSize)", (unsigned long)size, (unsigned long)serialized_size(saved));
        return fmi2Error;
    }
    uint64_t state_size = sizeof(SlaveState);
    uint64_t message = saved->refused == NULL ? 0 : strlen(saved->refused) + 1;
    char *p = serializedState;
    memcpy(p, STATE_MAGIC, sizeof(STATE_MAGIC)), p += sizeof(STATE_MAGIC);
    memcpy(p, MODEL_GUID, sizeof(MODEL_GUID)), p += sizeof(MODEL_GUID);
    memcpy(p, &state_size, sizeof(state_size)), p += sizeof(state_size);
    memcpy(p, &saved->state, sizeof(SlaveState)), p += sizeof(SlaveState);
    memcpy(p, &message, sizeof(message)), p += sizeof(message);
    if (message > 0) memcpy(p, saved->refused, (size_t)message);
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    Slave *slave = c;
    if (!legal(slave, "fmi2DeSerializeFMUstate", MASK_FMU_STATE)) return fmi2Error;
    const char *p = serializedState;
    uint64_t state_size = 0, message = 0;
    int valid = size >= HEADER_SIZE + sizeof(SlaveState) + sizeof(uint64_t)
                && memcmp(p, STATE_MAGIC, sizeof(STATE_MAGIC)) == 0
                && memcmp(p + sizeof(STATE_MAGIC), MODEL_GUID, sizeof(MODEL_GUID)) == 0;
    if (valid) {
        memcpy(&state_size, p + HEADER_SIZE - sizeof(uint64_t), sizeof(state_size));
        memcpy(&message, p + HEADER_SIZE + sizeof(SlaveState), sizeof(message));
        valid = state_size == sizeof(SlaveState)
                && size == HEADER_SIZE + sizeof(SlaveState) + sizeof(uint64_t) + message
                && (message == 0 || p[size - 1] == '\0');
    }
    if (!valid) {
        slave_log(slave, fmi2Error, "fmi2DeSerializeFMUstate: the %lu bytes are not a state serialised by "
                  "this FMU (GUID %s)", (unsigned long)size, MODEL_GUID);
        return fmi2Error;
    }
    SavedState *saved = calloc(1, sizeof(SavedState));
    if (saved == NULL) {
        slave_log(slave, fmi2Error, "fmi2DeSerializeFMUstate: out of memory");
        return fmi2Error;
    }
    memcpy(saved->magic, STATE_MAGIC, sizeof(STATE_MAGIC));
    memcpy(&saved->state, p + HEADER_SIZE, sizeof(SlaveState));
    saved->refused = message > 0 ? copy_string(p + HEADER_SIZE + sizeof(SlaveState) + sizeof(uint64_t)) : NULL;
    *FMUstate = saved;
    return fmi2OK;
}
