/* The machine's peak floating-point rate for `flightgp bench fmu` (validation/bench/fmu.py,
 * machine_peak_flops): independent fused multiply-adds on the widest vectors the processor runs
 * (AVX-512, else AVX2 + FMA, else SSE2 without FMA), enough of them in flight to hide the FMA
 * latency, in double and in single precision. What a kernel's FLOP rate is compared with.
 *
 * Usage: peak_flops; stdout: "double <GFLOP/s> single <GFLOP/s> <isa>" (best of 5 runs each).
 */
#define _POSIX_C_SOURCE 200809L
#include <stdio.h>
#include <time.h>

#define CHAINS 16          /* independent accumulators: above latency x FMA units */
#define ITERATIONS 2000000 /* per run: about 0.1 s on a few-GHz core */
#define RUNS 5

static double seconds(void) {
    struct timespec now;
    clock_gettime(CLOCK_MONOTONIC, &now);
    return now.tv_sec + 1e-9 * now.tv_nsec;
}

/* One kernel per element type and vector width: CHAINS accumulators acc = acc * a + b, each
 * multiply-add counted as 2 flops per lane. Returns the best rate of RUNS runs, flop/s. */
#define PEAK_KERNEL(name, type, bytes, target)                                                   \
    target static double name(void) {                                                            \
        typedef type vector __attribute__((vector_size(bytes)));                                 \
        const int lanes = bytes / (int)sizeof(type);                                             \
        double best = 0.0;                                                                       \
        for (int run = 0; run < RUNS; run++) {                                                   \
            vector acc[CHAINS], a, b;                                                            \
            for (int l = 0; l < lanes; l++) a[l] = (type)0.999999, b[l] = (type)1e-7;             \
            for (int c = 0; c < CHAINS; c++)                                                     \
                for (int l = 0; l < lanes; l++) acc[c][l] = (type)(c + l);                       \
            const double start = seconds();                                                      \
            for (long i = 0; i < ITERATIONS; i++)                                                \
                for (int c = 0; c < CHAINS; c++) acc[c] = acc[c] * a + b;                         \
            const double elapsed = seconds() - start;                                            \
            type sink = 0;                                                                       \
            for (int c = 0; c < CHAINS; c++)                                                     \
                for (int l = 0; l < lanes; l++) sink += acc[c][l];                               \
            if (sink == (type)-1) printf("%g\n", (double)sink); /* keeps the work */             \
            const double rate = 2.0 * lanes * CHAINS * (double)ITERATIONS / elapsed;             \
            if (rate > best) best = rate;                                                        \
        }                                                                                        \
        return best;                                                                             \
    }

#if defined(__x86_64__) && defined(__GNUC__)
PEAK_KERNEL(double_avx512, double, 64, __attribute__((target("avx512f,fma"))))
PEAK_KERNEL(single_avx512, float, 64, __attribute__((target("avx512f,fma"))))
PEAK_KERNEL(double_avx2, double, 32, __attribute__((target("avx2,fma"))))
PEAK_KERNEL(single_avx2, float, 32, __attribute__((target("avx2,fma"))))
#endif
PEAK_KERNEL(double_sse2, double, 16, )
PEAK_KERNEL(single_sse2, float, 16, )

int main(void) {
#if defined(__x86_64__) && defined(__GNUC__)
    __builtin_cpu_init();
    if (__builtin_cpu_supports("avx512f")) {
        printf("double %.3f single %.3f avx512\n", double_avx512() * 1e-9, single_avx512() * 1e-9);
        return 0;
    }
    if (__builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma")) {
        printf("double %.3f single %.3f avx2\n", double_avx2() * 1e-9, single_avx2() * 1e-9);
        return 0;
    }
#endif
    printf("double %.3f single %.3f sse2\n", double_sse2() * 1e-9, single_sse2() * 1e-9);
    return 0;
}
