/* The twin model behind the FMI 2.0 interface of nmsid_twin.c (see nmsid_model.c). */
#ifndef NMSID_MODEL_H
#define NMSID_MODEL_H

#include <stddef.h>

#include "fmi2Functions.h"
#include "twin_data.h"

#define NX 7          /* continuous states of a joint: path e [a, y, y'], path f [a, y, y'], c */
#define MAXN 5        /* largest augmented matrix (3 states + 2) */
#define HCAP 32768    /* input history (dead time): straight segments kept per joint */

/* One joint's twin: its variables (the value references of twin_data.h, N_REAL reals per
   joint), its input derivatives and its input history. A joint's variables are the ones of
   a one-joint FMU; the FMU's value reference of joint k's local reference v is
   k * N_REAL + v (N_INTEGER, N_BOOLEAN likewise), and its states are x[k * NX ...]. */
typedef struct {
    fmi2Real r[N_REAL];
    fmi2Integer i[N_INTEGER];
    fmi2Boolean b[N_BOOLEAN];
    fmi2Real der_rE, der_sE;       /* input derivatives for the next step (CS) */
    fmi2Real last_rE, last_sE;     /* inputs at the last completed integrator step (ME) */
    /* input history for the dead time: segments (t0, rE0, sE0, t1, rE1, sE1) of straight
       lines, oldest at h0, n of them; before the first one the inputs were at rest
       (rE = 0.5, sE = rest_sE) */
    double hist[HCAP][6];
    int h0, hn;
    double rest_sE;
} Joint;

typedef struct {
    Joint j[N_JOINTS];
    int in_init;
    fmi2Real time;
    const fmi2CallbackFunctions *cb;
    fmi2String name;
    int is_cs;
    int logging;
} Model;

void logmsg(Model *m, fmi2Status st, const char *cat, const char *fmt, ...);
const char *joint_name(const Model *m, const Joint *J);
int params_ok(Model *M, const Joint *J, double sE);
int advance_delayed(Model *M, Joint *J, double a, double b);
int hist_push(Model *M, Joint *J, double t0, double r0, double s0, double t1, double r1,
              double s1);
void hist_prune(Joint *J, double t);
double *hseg(Joint *J, int k);
void derivatives(Joint *J, double time, double *dx);
void outputs(Joint *J);
void seg_eval(Joint *J, int k, double t, double *r, double *s);
int seg_at(Joint *J, double t);

#endif
