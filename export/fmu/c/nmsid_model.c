/* nmsid digital twin: the model (the FMI 2.0 interface is in nmsid_twin.c).
 *
 * The model (docs/twin-file.md, docs/fmu.md):
 *   F(t) = offset_N(sE) + g(c) (y_e(t) - y_f(t))
 *   each path p: y_p'' + 2 zeta_p wn_p y_p' + wn_p^2 y_p = wn_p^2 a_p,
 *   a_p = w_p (no activation lag) or tau a_p' + a_p = w_p (activation_dynamics),
 *   w = Kp(sE) (rE - 0.5) on one path (no recruitment map, no asymmetry), or
 *   w_e = k (h(rE sE) - h(sE / 2)), w_f = k (h((1 - rE) sE) - h(sE / 2)), k = Kp / (2 sE).
 *   The state y_f holds minus the flexor's force (its drive is -w_f), so F sums the paths.
 *   dead_time: the dynamics see the inputs dead_time_s late (an input history of straight
 *   segments); fatigue: g(c), c = cumulative time with sE > 0.
 * Parameters are the twin's curves of sE, evaluated at sE clipped to [sE_min, sE_max]
 * unless `extrapolate` is set.
 *
 * Co-simulation: fmi2DoStep solves the linear dynamics exactly for inputs that are straight
 * lines over the step (the value set at the step's start plus the first derivative set by
 * fmi2SetRealInputDerivatives, zero when none is set), with wn and zeta the mean of their
 * values at the step's two ends: the triangle-hold discretisation of `nmsid twin simulate`
 * (analysis/twin.py), so a step equal to the sampling period reproduces it.
 * The transition matrices come from the matrix exponential of the augmented system
 * [[hA, hB, 0], [0, 0, 1], [0, 0, 0]] (C. Van Loan, "Computing integrals involving the
 * matrix exponential", IEEE TAC 23(3), 1978), by scaling and squaring of its Taylor series.
 *
 * Each function steps one joint's twin (Joint, nmsid_model.h); an FMU of several joints
 * holds N_JOINTS of them side by side, each with its own inputs, states and history.
 * Generated values (value references and the twin's parameters) are in twin_data.h.
 * Needs only the C standard library and libm; no Python at run time.
 */

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "nmsid_model.h"

void logmsg(Model *m, fmi2Status st, const char *cat, const char *fmt, ...)
{
    char buf[512];
    va_list ap;
    if (!m || !m->cb || !m->cb->logger) return;
    if (st == fmi2OK && !m->logging) return;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    m->cb->logger(m->cb->componentEnvironment, m->name, st, cat, "%s", buf);
}

/* the name of a joint of the FMU (twin_data.h), for messages */
const char *joint_name(const Model *m, const Joint *J)
{
    ptrdiff_t k = J - m->j;
    return k >= 0 && k < N_JOINTS ? JOINT_NAMES[k] : "?";
}

/* ---- the twin's curves and effects ------------------------------------------------ */

static double curve(int model, const double *c, double x)
{
    switch (model) {
    case 0: return c[0];                         /* constant    a            */
    case 1: return c[0] + c[1] * x;              /* linear      a + b x      */
    case 2: return c[0] + c[1] * x + c[2] * x * x; /* quadratic a + b x + c x^2 */
    default: return c[0] * exp(c[1] * x);        /* exponential a exp(b x)   */
    }
}

static double sE_eval(const Joint *J, double sE)
{
    if (J->b[VRB_extrapolate]) return sE;
    if (sE < J->r[VR_sE_min]) return J->r[VR_sE_min];
    if (sE > J->r[VR_sE_max]) return J->r[VR_sE_max];
    return sE;
}

static double Kp_at(const Joint *J, double sE)
{ return curve(J->i[VRI_Kp_model], &J->r[VR_Kp_c0], sE_eval(J, sE)); }
static double wn_at(const Joint *J, double sE)
{ return curve(J->i[VRI_wn_model], &J->r[VR_wn_c0], sE_eval(J, sE)); }
static double zeta_at(const Joint *J, double sE)
{ return curve(J->i[VRI_zeta_model], &J->r[VR_zeta_c0], sE_eval(J, sE)); }
static double offset_at(const Joint *J, double sE)
{ return curve(J->i[VRI_offset_model], &J->r[VR_offset_c0], sE_eval(J, sE)); }

static double logistic(double z) { return 0.5 * (1.0 + tanh(0.5 * z)); }

/* recruitment map h(I): h(0) = 0, h(1) = 1, unit slope outside [0, 1]
   (sim_backends/effects.py RecruitmentNonlinearity.h) */
static double recruit(const Joint *J, double x)
{
    double xin = x < 0.0 ? 0.0 : (x > 1.0 ? 1.0 : x), y, p1 = J->r[VR_recruitment_p1],
           p2 = J->r[VR_recruitment_p2];
    switch (J->i[VRI_recruitment_shape]) {
    case 1: y = pow(xin, p1); break;                                   /* power: gamma */
    case 2: {                                            /* sigmoid: slope, midpoint */
        double lo = logistic(-p1 * p2), hi = logistic(p1 * (1.0 - p2));
        y = (logistic(p1 * (xin - p2)) - lo) / (hi - lo);
        break; }
    case 3:                                   /* threshold_saturation: threshold, saturation */
        y = (xin - p1) / (p2 - p1);
        y = y < 0.0 ? 0.0 : (y > 1.0 ? 1.0 : y);
        break;
    default: y = xin;
    }
    return y + (x - xin);
}

static int two_paths(const Joint *J)
{ return J->r[VR_asym_wn_ratio] != 1.0 || J->r[VR_asym_zeta_ratio] != 1.0; }

/* drives of the extensor and flexor paths for inputs (rE, sE) */
static void drives(const Joint *J, double rE, double sE, double *we, double *wf)
{
    double kp = Kp_at(J, sE);
    if (J->i[VRI_recruitment_shape] == 0 && !two_paths(J)) {
        *we = kp * (rE - 0.5);
        *wf = 0.0;
        return;
    }
    if (!(sE > 0.0)) { *we = *wf = 0.0; return; }
    {
        double k = kp / (2.0 * sE), h0 = recruit(J, 0.5 * sE);
        *we = k * (recruit(J, rE * sE) - h0);
        *wf = -k * (recruit(J, (1.0 - rE) * sE) - h0);  /* sign: force = y_e + y_f */
    }
    if (!two_paths(J)) { *we += *wf; *wf = 0.0; }
}

static double fatigue_gain(const Joint *J, double c)
{
    double p = J->r[VR_fatigue_gain_loss_pct] / 100.0, cref = J->r[VR_fatigue_reference_stim_s];
    if (J->i[VRI_fatigue_shape] == 1) return pow(1.0 - p, c / cref);
    if (J->i[VRI_fatigue_shape] == 2) { double g = 1.0 - p * c / cref; return g > 0.05 ? g : 0.05; }
    return 1.0;
}

/* ---- linear algebra: exp of a small matrix ----------------------------------------- */

static void matmul(int n, const double *a, const double *b, double *out)
{
    double t[MAXN * MAXN];
    int i, j, k;
    for (i = 0; i < n; i++)
        for (j = 0; j < n; j++) {
            double s = 0.0;
            for (k = 0; k < n; k++) s += a[i * n + k] * b[k * n + j];
            t[i * n + j] = s;
        }
    memcpy(out, t, sizeof(double) * n * n);
}

static void expm(int n, const double *a, double *e)
{
    double norm = 0.0, as[MAXN * MAXN], term[MAXN * MAXN];
    int i, j, k, sq = 0;
    for (i = 0; i < n; i++) {
        double row = 0.0;
        for (j = 0; j < n; j++) row += fabs(a[i * n + j]);
        if (row > norm) norm = row;
    }
    while (norm > 0.125) { norm *= 0.5; sq++; }
    for (i = 0; i < n * n; i++) as[i] = ldexp(a[i], -sq);
    for (i = 0; i < n * n; i++) e[i] = term[i] = (i % (n + 1) == 0) ? 1.0 : 0.0;
    for (k = 1; k <= 18; k++) {                /* Taylor series: |A| <= 1/8, error < 1e-30 */
        matmul(n, term, as, term);
        for (i = 0; i < n * n; i++) { term[i] /= k; e[i] += term[i]; }
    }
    for (i = 0; i < sq; i++) matmul(n, e, e, e);
}

/* one path over a step of h s: state x (nx = 2: [y, y'], or 3: [a, y, y']) driven by
   the straight line from w0 to w1 */
static void path_step(int nx, double *x, double wn, double zeta, double tau, double h,
                      double w0, double w1)
{
    double m[MAXN * MAXN], e[MAXN * MAXN], xn[3];
    int n = nx + 2, i, j;
    memset(m, 0, sizeof m);
    if (nx == 2) {
        m[0 * n + 1] = h;
        m[1 * n + 0] = -wn * wn * h; m[1 * n + 1] = -2.0 * zeta * wn * h;
        m[1 * n + 2] = wn * wn * h;
    } else {
        m[0 * n + 0] = -h / tau; m[0 * n + 3] = h / tau;
        m[1 * n + 2] = h;
        m[2 * n + 0] = wn * wn * h; m[2 * n + 1] = -wn * wn * h;
        m[2 * n + 2] = -2.0 * zeta * wn * h;
    }
    m[nx * n + nx + 1] = 1.0;
    expm(n, m, e);
    for (i = 0; i < nx; i++) {
        double s = e[i * n + nx] * w0 + e[i * n + nx + 1] * (w1 - w0);
        for (j = 0; j < nx; j++) s += e[i * n + j] * x[j];
        xn[i] = s;
    }
    memcpy(x, xn, sizeof(double) * nx);
}

int params_ok(Model *M, const Joint *J, double sE)
{
    double wn = wn_at(J, sE), z = zeta_at(J, sE);
    if (wn > 0.0 && z > 0.0 && isfinite(Kp_at(J, sE)) && isfinite(offset_at(J, sE))) return 1;
    logmsg(M, fmi2Error, "logStatusError", "%s: wn_rad_s (%g) or zeta (%g) is not positive at "
           "sE = %g; keep sE in [%g, %g] or leave extrapolate off", joint_name(M, J), wn, z, sE,
           J->r[VR_sE_min], J->r[VR_sE_max]);
    return 0;
}

/* advance the states by h s with inputs moving in straight lines (r0, s0) -> (r1, s1) */
static int advance(Model *M, Joint *J, double h, double r0, double s0, double r1, double s1)
{
    double *x = &J->r[VR_x0];
    double wn = 0.5 * (wn_at(J, s0) + wn_at(J, s1)), z = 0.5 * (zeta_at(J, s0) + zeta_at(J, s1));
    double tau = J->r[VR_activation_tau_s], we0, wf0, we1, wf1;
    int nx = tau > 0.0 ? 3 : 2, off = tau > 0.0 ? 0 : 1;
    if (!params_ok(M, J, s0) || !params_ok(M, J, s1)) return 0;
    drives(J, r0, s0, &we0, &wf0);
    drives(J, r1, s1, &we1, &wf1);
    if (h > 0.0) {
        path_step(nx, x + off, wn, z, tau, h, we0, we1);
        if (two_paths(J))
            path_step(nx, x + 3 + off, wn * J->r[VR_asym_wn_ratio], z * J->r[VR_asym_zeta_ratio],
                      tau, h, wf0, wf1);
    }
    return 1;
}

/* ---- input history and the dead time --------------------------------------------- */

double *hseg(Joint *J, int k) { return J->hist[(J->h0 + k) % HCAP]; }

int hist_push(Model *M, Joint *J, double t0, double r0, double s0, double t1, double r1, double s1)
{
    double *g;
    if (J->hn == HCAP) {
        logmsg(M, fmi2Error, "logStatusError", "%s: dead_time %g s spans more than %d input "
               "steps; use longer steps", joint_name(M, J), J->r[VR_dead_time_s], HCAP);
        return 0;
    }
    g = hseg(J, J->hn++);
    g[0] = t0; g[1] = r0; g[2] = s0; g[3] = t1; g[4] = r1; g[5] = s1;
    return 1;
}

/* forget segments that end before t (never needed again) */
void hist_prune(Joint *J, double t)
{
    while (J->hn > 1 && hseg(J, 0)[3] < t) { J->h0 = (J->h0 + 1) % HCAP; J->hn--; }
}

/* inputs at time t on segment k (k < 0: at rest; past the last one: its end held) */
void seg_eval(Joint *J, int k, double t, double *r, double *s)
{
    double *g, a;
    if (k < 0) { *r = 0.5; *s = J->rest_sE; return; }
    g = hseg(J, k);
    if (g[3] <= g[0] || t >= g[3]) { *r = g[4]; *s = g[5]; return; }
    a = (t - g[0]) / (g[3] - g[0]);
    if (a < 0.0) a = 0.0;
    *r = g[1] + a * (g[4] - g[1]);
    *s = g[2] + a * (g[5] - g[2]);
}

/* the segment that holds the piece starting at t (-1 before the first) */
int seg_at(Joint *J, double t)
{
    int k;
    for (k = J->hn - 1; k >= 0; k--) if (hseg(J, k)[0] <= t) return k;
    return -1;
}

/* advance the states from a to b (times of the delayed input, i.e. minus the dead time),
   cutting the interval where the input history has a corner */
int advance_delayed(Model *M, Joint *J, double a, double b)
{
    while (b - a > 0.0) {
        int k = seg_at(J, a);
        double q = b, r0, s0, r1, s1;
        if (k + 1 < J->hn && hseg(J, k + 1)[0] < q) q = hseg(J, k + 1)[0];
        if (k >= 0 && hseg(J, k)[3] > a && hseg(J, k)[3] < q) q = hseg(J, k)[3];
        if (q - a <= 1e-12 * (fabs(a) + 1.0) && q < b) { a = q; continue; }
        seg_eval(J, k, a, &r0, &s0);
        seg_eval(J, k, q, &r1, &s1);
        if (!advance(M, J, q - a, r0, s0, r1, s1)) return 0;
        a = q;
    }
    return 1;
}

void derivatives(Joint *J, double time, double *dx)
{
    const double *x = &J->r[VR_x0];
    double rE = J->r[VR_rE], sE = J->r[VR_sE], tau = J->r[VR_activation_tau_s], wn, z;
    double w[2], stim = sE;
    int p;
    if (J->r[VR_dead_time_s] > 0.0) {
        double t = time - J->r[VR_dead_time_s];
        seg_eval(J, seg_at(J, t), t, &rE, &sE);
    }
    wn = wn_at(J, sE);
    z = zeta_at(J, sE);
    drives(J, rE, sE, &w[0], &w[1]);
    for (p = 0; p < 2; p++) {
        const double *xp = x + 3 * p;
        double *dp = dx + 3 * p;
        double wnp = p ? wn * J->r[VR_asym_wn_ratio] : wn, zp = p ? z * J->r[VR_asym_zeta_ratio] : z;
        double a = tau > 0.0 ? xp[0] : w[p];
        dp[0] = tau > 0.0 ? (w[p] - xp[0]) / tau : 0.0;
        dp[1] = xp[2];
        dp[2] = wnp * wnp * (a - xp[1]) - 2.0 * zp * wnp * xp[2];
    }
    dx[6] = stim > 0.0 ? 1.0 : 0.0;
}

void outputs(Joint *J)
{
    double sE = J->r[VR_sE], *x = &J->r[VR_x0];
    J->r[VR_Kp] = Kp_at(J, sE);
    J->r[VR_wn_rad_s] = wn_at(J, sE);
    J->r[VR_zeta] = zeta_at(J, sE);
    J->r[VR_force_N] = offset_at(J, sE) + fatigue_gain(J, x[6]) * (x[1] + x[4]);
}

