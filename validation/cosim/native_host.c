/* A minimal C host for FMI 2.0 co-simulation FMUs (validation/cosim/hosts.py, simulate_in_c_host):
 * dlopen the FMU's binary, then fmi2Instantiate, fmi2SetupExperiment, fmi2Enter/
 * ExitInitializationMode, and per step fmi2SetReal (inputs), fmi2DoStep, fmi2GetReal
 * (outputs); fmi2Terminate, fmi2FreeInstance. No Python is in this process: it proves a native
 * FMU runs in a plain C host, and times the FMU's step without any interpreter around it.
 *
 * Usage: native_host BINARY IDENTIFIER-UNUSED GUID RESOURCE_URI < script
 * script (whitespace-separated numbers):
 *   n_start   then n_start pairs "vr value"    Real start values (before initialisation)
 *   n_bool    then n_bool pairs "vr value"     Boolean start values
 *   n_in      then n_in value references       Real inputs set at every communication point
 *   n_out     then n_out value references      Real outputs read after initialisation and steps
 *   n_steps step repeats
 *   n_steps rows of n_in input values          inputs at t_k = k step (row 0 also before init)
 * stdout: one line of outputs (%.17g) after initialisation and after every step (first run),
 * then "us_per_step <best of repeats>" and "python_in_process <0|1>".
 * Exit status 0, or 1 with a message on stderr when a call returns fmi2Error or worse.
 */
#define _POSIX_C_SOURCE 200809L
#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "fmi2Functions.h"

static void logger(fmi2ComponentEnvironment environment, fmi2String instance, fmi2Status status,
                   fmi2String category, fmi2String message, ...) {
    (void)environment;
    va_list args;
    va_start(args, message);
    fprintf(stderr, "[%s %d %s] ", instance, (int)status, category);
    vfprintf(stderr, message, args);
    fputc('\n', stderr);
    va_end(args);
}

static void *symbol(void *library, const char *name) {
    void *function = dlsym(library, name);
    if (function == NULL) {
        fprintf(stderr, "the FMU's binary has no %s\n", name);
        exit(1);
    }
    return function;
}

static void check(fmi2Status status, const char *call) {
    if (status > fmi2Warning) {
        fprintf(stderr, "%s returned status %d\n", call, (int)status);
        exit(1);
    }
}

static double now(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static size_t read_count(void) {
    long n;
    if (scanf("%ld", &n) != 1 || n < 0) {
        fprintf(stderr, "bad script\n");
        exit(1);
    }
    return (size_t)n;
}

static double read_number(void) {
    double x;
    if (scanf("%lf", &x) != 1) {
        fprintf(stderr, "bad script\n");
        exit(1);
    }
    return x;
}

static void *allocate(size_t n, size_t size) {
    void *p = calloc(n > 0 ? n : 1, size);
    if (p == NULL) {
        fprintf(stderr, "out of memory\n");
        exit(1);
    }
    return p;
}

int main(int argc, char **argv) {
    if (argc != 5) {
        fprintf(stderr, "usage: %s BINARY IDENTIFIER GUID RESOURCE_URI < script\n", argv[0]);
        return 1;
    }
    void *library = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (library == NULL) {
        fprintf(stderr, "dlopen: %s\n", dlerror());
        return 1;
    }
    fmi2InstantiateTYPE *instantiate = (fmi2InstantiateTYPE *)symbol(library, "fmi2Instantiate");
    fmi2SetupExperimentTYPE *setup = (fmi2SetupExperimentTYPE *)symbol(library, "fmi2SetupExperiment");
    fmi2EnterInitializationModeTYPE *enter = (fmi2EnterInitializationModeTYPE *)symbol(library, "fmi2EnterInitializationMode");
    fmi2ExitInitializationModeTYPE *leave = (fmi2ExitInitializationModeTYPE *)symbol(library, "fmi2ExitInitializationMode");
    fmi2SetRealTYPE *set_real = (fmi2SetRealTYPE *)symbol(library, "fmi2SetReal");
    fmi2SetBooleanTYPE *set_boolean = (fmi2SetBooleanTYPE *)symbol(library, "fmi2SetBoolean");
    fmi2GetRealTYPE *get_real = (fmi2GetRealTYPE *)symbol(library, "fmi2GetReal");
    fmi2DoStepTYPE *do_step = (fmi2DoStepTYPE *)symbol(library, "fmi2DoStep");
    fmi2ResetTYPE *reset = (fmi2ResetTYPE *)symbol(library, "fmi2Reset");
    fmi2TerminateTYPE *terminate = (fmi2TerminateTYPE *)symbol(library, "fmi2Terminate");
    fmi2FreeInstanceTYPE *free_instance = (fmi2FreeInstanceTYPE *)symbol(library, "fmi2FreeInstance");

    size_t n_start = read_count();
    fmi2ValueReference *start_vr = allocate(n_start, sizeof(fmi2ValueReference));
    double *start = allocate(n_start, sizeof(double));
    for (size_t i = 0; i < n_start; i++) start_vr[i] = (fmi2ValueReference)read_number(), start[i] = read_number();
    size_t n_bool = read_count();
    fmi2ValueReference *bool_vr = allocate(n_bool, sizeof(fmi2ValueReference));
    fmi2Boolean *bools = allocate(n_bool, sizeof(fmi2Boolean));
    for (size_t i = 0; i < n_bool; i++) bool_vr[i] = (fmi2ValueReference)read_number(), bools[i] = read_number() != 0.0;
    size_t n_in = read_count();
    fmi2ValueReference *in_vr = allocate(n_in, sizeof(fmi2ValueReference));
    for (size_t i = 0; i < n_in; i++) in_vr[i] = (fmi2ValueReference)read_number();
    size_t n_out = read_count();
    fmi2ValueReference *out_vr = allocate(n_out, sizeof(fmi2ValueReference));
    for (size_t i = 0; i < n_out; i++) out_vr[i] = (fmi2ValueReference)read_number();
    size_t n_steps = read_count();
    double step = read_number();
    size_t repeats = read_count();
    double *inputs = allocate((n_steps + 1) * n_in, sizeof(double));
    for (size_t i = 0; i < (n_steps + 1) * n_in; i++) inputs[i] = read_number();
    double *outputs = allocate((n_steps + 1) * n_out, sizeof(double));

    fmi2CallbackFunctions callbacks = {logger, NULL, NULL, NULL, NULL};
    fmi2Component fmu = instantiate("c_host", fmi2CoSimulation, argv[3], argv[4], &callbacks, fmi2False, fmi2False);
    if (fmu == NULL) {
        fprintf(stderr, "fmi2Instantiate failed\n");
        return 1;
    }
    double best = 1e300;
    for (size_t run = 0; run < (repeats > 0 ? repeats : 1); run++) {
        if (run > 0) check(reset(fmu), "fmi2Reset");
        check(set_real(fmu, start_vr, n_start, start), "fmi2SetReal (start values)");
        check(set_boolean(fmu, bool_vr, n_bool, bools), "fmi2SetBoolean (start values)");
        check(set_real(fmu, in_vr, n_in, inputs), "fmi2SetReal (inputs at t0)");
        check(setup(fmu, fmi2False, 0.0, 0.0, fmi2False, 0.0), "fmi2SetupExperiment");
        check(enter(fmu), "fmi2EnterInitializationMode");
        check(leave(fmu), "fmi2ExitInitializationMode");
        check(get_real(fmu, out_vr, n_out, outputs), "fmi2GetReal");
        double begin = now();
        for (size_t k = 0; k < n_steps; k++) { /* t_k = k h from the step counter */
            check(set_real(fmu, in_vr, n_in, inputs + k * n_in), "fmi2SetReal");
            check(do_step(fmu, (double)k * step, step, fmi2True), "fmi2DoStep");
            check(get_real(fmu, out_vr, n_out, outputs + (k + 1) * n_out), "fmi2GetReal");
        }
        double per_step = (now() - begin) / (double)(n_steps > 0 ? n_steps : 1);
        if (per_step < best) best = per_step;
        if (run == 0)
            for (size_t k = 0; k <= n_steps; k++) {
                for (size_t i = 0; i < n_out; i++) printf(i ? " %.17g" : "%.17g", outputs[k * n_out + i]);
                printf("\n");
            }
    }
    check(terminate(fmu), "fmi2Terminate");
    free_instance(fmu);
    printf("us_per_step %.17g\n", best * 1e6);
    /* Is any Python runtime mapped into this process? (Linux: /proc/self/maps) */
    int python = 0;
    FILE *maps = fopen("/proc/self/maps", "r");
    if (maps != NULL) {
        int c, matched = 0;
        const char *needle = "libpython";
        while ((c = fgetc(maps)) != EOF && !python) {
            matched = c == needle[matched] ? matched + 1 : (c == needle[0]);
            python = needle[matched] == '\0';
        }
        fclose(maps);
    }
    printf("python_in_process %d\n", python);
    dlclose(library);
    free(start_vr), free(start), free(bool_vr), free(bools), free(in_vr), free(out_vr), free(inputs), free(outputs);
    return 0;
}
