/* hypa's sample loop over an FMI 2.0 FMU (hypa/physics/fmu_loop.py compiles and loads it).

   The loops of hypa.physics.fmu.FMUSimulator, unchanged in arithmetic, with every call into the FMU made
   from C through the FMU's own function pointers instead of one Python call each: a free run in model
   exchange (hypa's RK4 with `count` substeps per sample, the inputs held as the line from u_k to u_k+1 or
   at u_k), its per-sample sensitivities by forward differences, and a co-simulation run (fmi2DoStep).

   A call whose status is worse than fmi2Warning stops the loop: the functions return HYPA_FAILED and
   `failed` names the call (FAILED_*) and `at` its sample. */

#include <math.h>
#include <stddef.h>
#include <string.h>

typedef int (*set_time_t)(void *, double);
typedef int (*set_states_t)(void *, const double *, size_t);
typedef int (*set_real_t)(void *, const unsigned int *, size_t, const double *);
typedef int (*get_derivatives_t)(void *, double *, size_t);
typedef int (*get_real_t)(void *, const unsigned int *, size_t, double *);
typedef int (*do_step_t)(void *, double, double, int);
typedef int (*set_input_derivatives_t)(void *, const unsigned int *, size_t, const int *, const double *);

enum { FAILED_NONE, FAILED_SET_TIME, FAILED_SET_STATES, FAILED_SET_REAL, FAILED_GET_DERIVATIVES, FAILED_GET_REAL,
       FAILED_DO_STEP, FAILED_SET_INPUT_DERIVATIVES };
#define HYPA_FAILED (-1)
#define STATUS_WORST_ACCEPTED 1 /* fmi2OK 0, fmi2Warning 1; fmi2Discard, fmi2Error, fmi2Fatal stop */

/* the scratch a loop needs: RK4's four slopes, its stage, the held inputs, the next state, the moved
   state and inputs of a difference, its outputs and its stepped state */
#define HYPA_WORK(n, m, p) (9 * (n) + 4 * (m) + (p))

typedef struct {
    void *component;
    set_time_t set_time;
    set_states_t set_states;
    set_real_t set_real;
    get_derivatives_t get_derivatives;
    get_real_t get_real;
    do_step_t do_step;
    set_input_derivatives_t set_input_derivatives;
    int n, m, p; /* states, inputs fed, outputs read */
    const unsigned int *inputs, *outputs;
    double *work; /* scratch of HYPA_WORK(n, m, p) doubles */
    int *order;   /* scratch of m ints */
    int failed; /* FAILED_* of the call that stopped a loop */
    long at;    /* its sample */
} hypa_fmu;

#define CALL(api, expr, code)                                                                                      \
    do {                                                                                                           \
        if ((expr) > STATUS_WORST_ACCEPTED) {                                                                      \
            (api)->failed = (code);                                                                                \
            return HYPA_FAILED;                                                                                    \
        }                                                                                                          \
    } while (0)

static int derivatives(hypa_fmu *api, double t, const double *x, const double *u, double *dx) {
    CALL(api, api->set_time(api->component, t), FAILED_SET_TIME);
    CALL(api, api->set_states(api->component, x, (size_t)api->n), FAILED_SET_STATES);
    if (api->m) CALL(api, api->set_real(api->component, api->inputs, (size_t)api->m, u), FAILED_SET_REAL);
    CALL(api, api->get_derivatives(api->component, dx, (size_t)api->n), FAILED_GET_DERIVATIVES);
    return 0;
}

static int outputs(hypa_fmu *api, double t, const double *x, const double *u, double *y) {
    CALL(api, api->set_time(api->component, t), FAILED_SET_TIME);
    if (api->n) CALL(api, api->set_states(api->component, x, (size_t)api->n), FAILED_SET_STATES);
    if (api->m) CALL(api, api->set_real(api->component, api->inputs, (size_t)api->m, u), FAILED_SET_REAL);
    CALL(api, api->get_real(api->component, api->outputs, (size_t)api->p, y), FAILED_GET_REAL);
    return 0;
}

/* x_next from x at t by `count` RK4 substeps, the inputs the line from u to u_next (equal: a zero-order
   hold); the arithmetic of FMUSimulator._step. x_next may not alias x. */
static int step(hypa_fmu *api, double t, const double *x, const double *u, const double *u_next, double dt,
                int count, double *x_next) {
    const int n = api->n, m = api->m;
    double *k1 = api->work, *k2 = k1 + n, *k3 = k2 + n, *k4 = k3 + n, *stage = k4 + n, *held = stage + n;
    const double h = dt / count;
    memcpy(x_next, x, sizeof(double) * (size_t)n);
    for (int i = 0; i < count; i++) {
        const double a = t + i * h, s = (double)i / count;
        const double s_mid = s + 0.5 / count, s_end = s + 1.0 / count;
        for (int j = 0; j < m; j++) held[j] = u[j] + s * (u_next[j] - u[j]);
        if (derivatives(api, a, x_next, held, k1)) return HYPA_FAILED;
        for (int j = 0; j < m; j++) held[j] = u[j] + s_mid * (u_next[j] - u[j]);
        for (int j = 0; j < n; j++) stage[j] = x_next[j] + h / 2 * k1[j];
        if (derivatives(api, a + h / 2, stage, held, k2)) return HYPA_FAILED;
        for (int j = 0; j < n; j++) stage[j] = x_next[j] + h / 2 * k2[j];
        if (derivatives(api, a + h / 2, stage, held, k3)) return HYPA_FAILED;
        for (int j = 0; j < m; j++) held[j] = u[j] + s_end * (u_next[j] - u[j]);
        for (int j = 0; j < n; j++) stage[j] = x_next[j] + h * k3[j];
        if (derivatives(api, a + h, stage, held, k4)) return HYPA_FAILED;
        for (int j = 0; j < n; j++) x_next[j] = x_next[j] + h / 6 * (k1[j] + 2 * k2[j] + 2 * k3[j] + k4[j]);
    }
    return 0;
}

/* the scratch after step()'s: the next state (n), the moved state and inputs (n, m, m), outputs (p), the
   stepped state (n) */
static double *after_step(const hypa_fmu *api) { return api->work + 5 * api->n + api->m; }

static int fits(const hypa_fmu *api) {
    return api->n >= 0 && api->m >= 0 && api->p >= 0 && api->work != NULL && (api->m == 0 || api->order != NULL);
}

/* Model exchange: y (T, p) and the states xs (T, n) from x (n; left at the last state) and u (T, m). */
int hypa_me_run(hypa_fmu *api, const double *u, long steps, double t0, double dt, int count, int foh, double *x,
                double *y, double *xs) {
    const int n = api->n, m = api->m, p = api->p;
    double *next = after_step(api);
    if (!fits(api)) return HYPA_FAILED;
    for (long k = 0; k < steps; k++) {
        api->at = k;
        if (outputs(api, t0 + k * dt, x, u + k * m, y + k * p)) return HYPA_FAILED;
        memcpy(xs + k * n, x, sizeof(double) * (size_t)n);
        if (k + 1 < steps) {
            const double *later = foh ? u + (k + 1) * m : u + k * m;
            if (step(api, t0 + k * dt, x, u + k * m, later, dt, count, next)) return HYPA_FAILED;
            memcpy(x, next, sizeof(double) * (size_t)n);
        }
    }
    return 0;
}

/* Per sample k of a run (xs, ys): y_x (T, p, n), y_u (T, p, m), x_x (T, n, n), x_u (T, n, m), x_u_next
   (T, n, m), by forward differences with steps sqrt(eps) max(|v|, 1) (FMUSimulator.sensitivities). */
int hypa_me_sensitivities(hypa_fmu *api, const double *u, long steps, double t0, double dt, int count, int foh,
                          const double *xs, const double *ys, double *y_x, double *y_u, double *x_x, double *x_u,
                          double *x_u_next) {
    const int n = api->n, m = api->m, p = api->p;
    double *moved[3], *y, *after;
    const double root_eps = sqrt(2.220446049250313e-16);
    if (!fits(api)) return HYPA_FAILED;
    moved[0] = after_step(api) + n;
    moved[1] = moved[0] + n;
    moved[2] = moved[1] + m;
    y = moved[2] + m;
    after = y + p;
    for (long k = 0; k < steps; k++) {
        const double t = t0 + k * dt;
        const double *x = xs + k * n, *now = u + k * m, *later = k + 1 < steps ? u + (k + 1) * m : now;
        const int stepped = k + 1 < steps;
        const int columns = n + m + (foh && stepped ? m : 0);
        api->at = k;
        for (int i = 0; i < columns; i++) {
            const int which = i < n ? 0 : i < n + m ? 1 : 2, column = i < n ? i : i < n + m ? i - n : i - n - m;
            const double *base = which == 0 ? x : which == 1 ? now : later;
            const double delta = root_eps * fmax(fabs(base[column]), 1.0);
            memcpy(moved[0], x, sizeof(double) * (size_t)n);
            memcpy(moved[1], now, sizeof(double) * (size_t)m);
            memcpy(moved[2], later, sizeof(double) * (size_t)m);
            moved[which][column] = base[column] + delta;
            if (which < 2) {
                double *target = which == 0 ? y_x + k * p * n : y_u + k * p * m;
                const int width = which == 0 ? n : m;
                if (outputs(api, t, moved[0], moved[1], y)) return HYPA_FAILED;
                for (int r = 0; r < p; r++) target[r * width + column] = (y[r] - ys[k * p + r]) / delta;
            }
            if (stepped) {
                double *target = which == 0 ? x_x + k * n * n : which == 1 ? x_u + k * n * m : x_u_next + k * n * m;
                const int width = which == 0 ? n : m;
                if (step(api, t, moved[0], moved[1], foh ? moved[2] : moved[1], dt, count, after)) return HYPA_FAILED;
                for (int r = 0; r < n; r++) target[r * width + column] = (after[r] - xs[(k + 1) * n + r]) / delta;
            }
        }
    }
    return 0;
}

/* Co-simulation: y (T, p) from u (T, m), fmi2DoStep(t0 + k dt, dt) between samples; a first-order hold
   by fmi2SetRealInputDerivatives (order 1, the slope to the next sample). */
int hypa_cs_run(hypa_fmu *api, const double *u, long steps, double t0, double dt, int foh, double *y) {
    const int m = api->m, p = api->p;
    int *order = api->order;
    double *slope = api->work;
    if (!fits(api)) return HYPA_FAILED;
    for (int j = 0; j < m; j++) order[j] = 1;
    for (long k = 0; k < steps; k++) {
        api->at = k;
        if (m) {
            CALL(api, api->set_real(api->component, api->inputs, (size_t)m, u + k * m), FAILED_SET_REAL);
            if (foh && k + 1 < steps) {
                for (int j = 0; j < m; j++) slope[j] = (u[(k + 1) * m + j] - u[k * m + j]) / dt;
                CALL(api, api->set_input_derivatives(api->component, api->inputs, (size_t)m, order, slope),
                     FAILED_SET_INPUT_DERIVATIVES);
            }
        }
        CALL(api, api->get_real(api->component, api->outputs, (size_t)p, y + k * p), FAILED_GET_REAL);
        if (k + 1 < steps) CALL(api, api->do_step(api->component, t0 + k * dt, dt, 1), FAILED_DO_STEP);
    }
    return 0;
}
