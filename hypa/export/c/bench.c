/* hypa's C step, timed (hypa.export.native.time_c_step): bench DATA prints the nanoseconds per step, the
   steps timed and a checksum of the outputs. DATA: the row count (int64), the initial state (r doubles), the
   input rows (rows x m doubles). The rows run in turn from the initial state, again from the first when all
   have run; the steps double from 16 until a run takes BENCH_SECONDS or BENCH_MAX_STEPS steps. */
#define _POSIX_C_SOURCE 199309L
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "step.c"

#define BENCH_BUFFER(n) ((n) > 0 ? (n) : 1)
#define BENCH_SECONDS 0.2
#define BENCH_MAX_STEPS 1000000L

static double bench_now(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static double bench_run(const double *x0, const double *u, long rows, long steps, double *checksum) {
    double a[BENCH_BUFFER(HYPA_STATE_SIZE)], b[BENCH_BUFFER(HYPA_STATE_SIZE)], y[BENCH_BUFFER(HYPA_OUTPUT_SIZE)];
    double *state = a, *next = b, *swap, started;
    long k, row = 0;
    int j;
    memcpy(a, x0, sizeof a);
    started = bench_now();
    for (k = 0; k < steps; k++) {
        hypa_step(state, u + row * HYPA_INPUT_SIZE, next, y);
        for (j = 0; j < HYPA_OUTPUT_SIZE; j++) *checksum += y[j];
        swap = state;
        state = next;
        next = swap;
        if (++row == rows) {
            row = 0;
            memcpy(state, x0, sizeof a);
        }
    }
    return bench_now() - started;
}

int main(int argc, char **argv) {
    FILE *file;
    int64_t rows;
    size_t values;
    double *x0, *u, seconds, checksum = 0.0;
    long steps = 16;
    if (argc != 2 || (file = fopen(argv[1], "rb")) == NULL) {
        fprintf(stderr, "usage: bench DATA\n");
        return 2;
    }
    if (fread(&rows, sizeof rows, 1, file) != 1 || rows < 1) {
        fprintf(stderr, "bench: no rows in %s\n", argv[1]);
        return 2;
    }
    values = (size_t)rows * (size_t)HYPA_INPUT_SIZE;
    x0 = (double *)calloc(BENCH_BUFFER(HYPA_STATE_SIZE), sizeof *x0);
    u = (double *)calloc(values > 0 ? values : 1, sizeof *u);
    if (x0 == NULL || u == NULL || fread(x0, sizeof *x0, (size_t)HYPA_STATE_SIZE, file) != (size_t)HYPA_STATE_SIZE
        || fread(u, sizeof *u, values, file) != values) {
        fprintf(stderr, "bench: %s is short\n", argv[1]);
        return 2;
    }
    fclose(file);
    for (;;) {
        seconds = bench_run(x0, u, (long)rows, steps, &checksum);
        if (seconds >= BENCH_SECONDS || steps >= BENCH_MAX_STEPS) break;
        steps = 2 * steps < BENCH_MAX_STEPS ? 2 * steps : BENCH_MAX_STEPS;
    }
    printf("%.9g %ld %.17g\n", 1e9 * seconds / (double)steps, steps, checksum);
    free(x0);
    free(u);
    return 0;
}
