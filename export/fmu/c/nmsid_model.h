/* The twin model behind the FMI 2.0 interface of nmsid_twin.c (see nmsid_model.c). */
#ifndef NMSID_MODEL_H
#define NMSID_MODEL_H

#include "fmi2Functions.h"
#include "twin_data.h"

#define NX 7          /* continuous states: path e [a, y, y'], path f [a, y, y'], c */
#define MAXN 5        /* largest augmented matrix (3 states + 2) */
#define HCAP 32768    /* input history (dead time): straight segments kept */

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
    int in_init;
    fmi2Real time;
    const fmi2CallbackFunctions *cb;
    fmi2String name;
    int is_cs;
    int logging;
} Model;

void logmsg(Model *m, fmi2Status st, const char *cat, const char *fmt, ...);
int params_ok(Model *m, double sE);
int advance_delayed(Model *m, double a, double b);
int hist_push(Model *m, double t0, double r0, double s0, double t1, double r1, double s1);
void hist_prune(Model *m, double t);
double *hseg(Model *m, int k);
void derivatives(Model *m, double *dx);
void outputs(Model *m);
void seg_eval(Model *m, int k, double t, double *r, double *s);
int seg_at(Model *m, double t);

#endif
