/* hypa's sample loop over an FMI 2.0 or 3.0 FMU (hypa/physics/fmu_loop.py compiles and loads it).

   The loops of hypa.physics.fmu.FMUSimulator, unchanged in arithmetic, with every call into the FMU made
   from C through the FMU's own function pointers instead of one Python call each: a free run in model
   exchange (hypa's RK4 with `count` substeps per sample, the inputs held as the line from u_k to u_k+1 or
   at u_k; each sample a completed integrator step, its event indicators watched), its per-sample
   sensitivities by forward differences, and a co-simulation run (fmi2DoStep / fmi3DoStep).

   A call whose status is worse than a warning stops the loop: the functions return HYPA_FAILED and
   `failed` names the call (FAILED_*) and `at` its sample; so does an event the loop cannot handle (an
   event indicator changing sign, an FMU asking for event mode or to terminate). */

#include <math.h>
#include <stdbool.h>
#include <stddef.h>
#include <string.h>

typedef void (*fn_t)(void); /* any function: stored as this, called as its own type */
/* FMI 2.0 (fmi2Boolean is an int) */
typedef int (*set_time_t)(void *, double);
typedef int (*set_states_t)(void *, const double *, size_t);
typedef int (*set_real2_t)(void *, const unsigned int *, size_t, const double *);
typedef int (*get_derivatives_t)(void *, double *, size_t);
typedef int (*get_real2_t)(void *, const unsigned int *, size_t, double *);
typedef int (*do_step2_t)(void *, double, double, int);
typedef int (*set_input_derivatives_t)(void *, const unsigned int *, size_t, const int *, const double *);
typedef int (*completed2_t)(void *, int, int *, int *);
typedef int (*get_event_indicators_t)(void *, double *, size_t);
/* FMI 3.0 (fmi3Boolean is a bool; Float64 arrays carry their number of values) */
typedef int (*set_real3_t)(void *, const unsigned int *, size_t, const double *, size_t);
typedef int (*get_real3_t)(void *, const unsigned int *, size_t, double *, size_t);
typedef int (*do_step3_t)(void *, double, double, bool, bool *, bool *, bool *, double *);
typedef int (*completed3_t)(void *, bool, bool *, bool *);

enum { FAILED_NONE, FAILED_SET_TIME, FAILED_SET_STATES, FAILED_SET_REAL, FAILED_GET_DERIVATIVES, FAILED_GET_REAL,
       FAILED_DO_STEP, FAILED_SET_INPUT_DERIVATIVES, FAILED_COMPLETED_STEP, FAILED_GET_EVENT_INDICATORS,
       EVENT_STATE, EVENT_STEP, EVENT_TERMINATE, EVENT_CO_SIMULATION };
#define HYPA_FAILED (-1)
#define STATUS_WORST_ACCEPTED 1 /* OK 0, Warning 1; Discard, Error, Fatal stop (FMI 2.0 and 3.0 alike) */

/* the scratch a loop needs: RK4's four slopes, its stage, the held inputs, the next state, the moved
   state and inputs of a difference, its outputs and its stepped state */
#define HYPA_WORK(n, m, p, e) (9 * (n) + 4 * (m) + (p) + 2 * (e))

typedef struct {
    void *component;
    fn_t set_time, set_states, set_real, get_derivatives, get_real, do_step, set_input_derivatives, completed_step,
        get_event_indicators; /* the FMU's functions, each cast to its type (2.0 or 3.0) where called */
    int version;    /* 2 or 3 */
    int n, m, p, e; /* states, inputs fed, outputs read, event indicators */
    const unsigned int *inputs, *outputs;
    double *work; /* scratch of HYPA_WORK(n, m, p, e) doubles */
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

#define STOP(api, code)                                                                                            \
    do {                                                                                                           \
        (api)->failed = (code);                                                                                    \
        return HYPA_FAILED;                                                                                        \
    } while (0)

static int set_inputs(hypa_fmu *api, const double *u) {
    if (!api->m) return 0;
    if (api->version == 3)
        CALL(api, ((set_real3_t)api->set_real)(api->component, api->inputs, (size_t)api->m, u, (size_t)api->m),
             FAILED_SET_REAL);
    else
        CALL(api, ((set_real2_t)api->set_real)(api->component, api->inputs, (size_t)api->m, u), FAILED_SET_REAL);
    return 0;
}

static int get_outputs(hypa_fmu *api, double *y) {
    if (api->version == 3)
        CALL(api, ((get_real3_t)api->get_real)(api->component, api->outputs, (size_t)api->p, y, (size_t)api->p),
             FAILED_GET_REAL);
    else
        CALL(api, ((get_real2_t)api->get_real)(api->component, api->outputs, (size_t)api->p, y), FAILED_GET_REAL);
    return 0;
}

static int set_time_and_states(hypa_fmu *api, double t, const double *x) {
    CALL(api, ((set_time_t)api->set_time)(api->component, t), FAILED_SET_TIME);
    if (api->n) CALL(api, ((set_states_t)api->set_states)(api->component, x, (size_t)api->n), FAILED_SET_STATES);
    return 0;
}

static int derivatives(hypa_fmu *api, double t, const double *x, const double *u, double *dx) {
    if (set_time_and_states(api, t, x) || set_inputs(api, u)) return HYPA_FAILED;
    CALL(api, ((get_derivatives_t)api->get_derivatives)(api->component, dx, (size_t)api->n), FAILED_GET_DERIVATIVES);
    return 0;
}

/* The sample's step is complete (the FMU at its time, states and inputs): fmi2/3CompletedIntegratorStep (with
   noSetFMUStatePriorToCurrentPoint false: the sensitivities set earlier times and states afterwards), and
   the event indicators against the last sample's (`last`, e values; `first`: none yet), stopping at an event
   the loop does not handle. */
static int completed(hypa_fmu *api, double *last, int first) {
    if (api->completed_step && !first) {
        if (api->version == 3) {
            bool event = false, terminate = false;
            CALL(api, ((completed3_t)api->completed_step)(api->component, false, &event, &terminate),
                 FAILED_COMPLETED_STEP);
            if (terminate) STOP(api, EVENT_TERMINATE);
            if (event) STOP(api, EVENT_STEP);
        } else {
            int event = 0, terminate = 0;
            CALL(api, ((completed2_t)api->completed_step)(api->component, 0, &event, &terminate),
                 FAILED_COMPLETED_STEP);
            if (terminate) STOP(api, EVENT_TERMINATE);
            if (event) STOP(api, EVENT_STEP);
        }
    }
    if (api->e) {
        double *now = last + api->e;
        CALL(api, ((get_event_indicators_t)api->get_event_indicators)(api->component, now, (size_t)api->e),
             FAILED_GET_EVENT_INDICATORS);
        for (int i = 0; i < api->e && !first; i++)
            if ((last[i] > 0) != (now[i] > 0)) STOP(api, EVENT_STATE);
        memcpy(last, now, sizeof(double) * (size_t)api->e);
    }
    return 0;
}

/* The outputs at (t, x, u); `watch`: the sample ends a completed step (the free run's), see completed(). */
static int outputs(hypa_fmu *api, double t, const double *x, const double *u, double *y, double *watch, int first) {
    if (set_time_and_states(api, t, x) || set_inputs(api, u)) return HYPA_FAILED;
    if (watch && completed(api, watch, first)) return HYPA_FAILED;
    return get_outputs(api, y);
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

/* the event indicators' scratch (2 e), after everything else */
static double *indicators(const hypa_fmu *api) { return api->work + 9 * api->n + 4 * api->m + api->p; }

static int fits(const hypa_fmu *api) {
    return api->n >= 0 && api->m >= 0 && api->p >= 0 && api->e >= 0 && api->work != NULL &&
           (api->m == 0 || api->order != NULL) && (api->version == 2 || api->version == 3) &&
           (api->e == 0 || api->get_event_indicators != NULL);
}

/* Model exchange: y (T, p) and the states xs (T, n) from x (n; left at the last state) and u (T, m). */
int hypa_me_run(hypa_fmu *api, const double *u, long steps, double t0, double dt, int count, int foh, double *x,
                double *y, double *xs) {
    const int n = api->n, m = api->m, p = api->p;
    double *next = after_step(api);
    if (!fits(api)) return HYPA_FAILED;
    for (long k = 0; k < steps; k++) {
        api->at = k;
        if (outputs(api, t0 + k * dt, x, u + k * m, y + k * p, indicators(api), k == 0)) return HYPA_FAILED;
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
                if (outputs(api, t, moved[0], moved[1], y, NULL, 0)) return HYPA_FAILED;
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
    (void)p;
    double *slope = api->work;
    if (!fits(api)) return HYPA_FAILED;
    for (int j = 0; j < m; j++) order[j] = 1;
    for (long k = 0; k < steps; k++) {
        api->at = k;
        if (set_inputs(api, u + k * m)) return HYPA_FAILED;
        if (m && foh && k + 1 < steps) { /* FMI 2.0 only: FMI 3.0 has no input derivatives (refused before) */
            for (int j = 0; j < m; j++) slope[j] = (u[(k + 1) * m + j] - u[k * m + j]) / dt;
            CALL(api, ((set_input_derivatives_t)api->set_input_derivatives)(api->component, api->inputs, (size_t)m,
                                                                            order, slope),
                 FAILED_SET_INPUT_DERIVATIVES);
        }
        if (get_outputs(api, y + k * p)) return HYPA_FAILED;
        if (k + 1 < steps) {
            if (api->version == 3) {
                bool event = false, terminate = false, early = false;
                double reached = 0.0;
                CALL(api, ((do_step3_t)api->do_step)(api->component, t0 + k * dt, dt, true, &event, &terminate,
                                                     &early, &reached),
                     FAILED_DO_STEP);
                if (terminate || early) STOP(api, terminate ? EVENT_TERMINATE : EVENT_CO_SIMULATION);
            } else {
                CALL(api, ((do_step2_t)api->do_step)(api->component, t0 + k * dt, dt, 1), FAILED_DO_STEP);
            }
        }
    }
    return 0;
}
