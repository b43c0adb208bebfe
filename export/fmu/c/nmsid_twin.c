/* nmsid digital twin as an FMI 2.0 FMU (model exchange and co-simulation): the FMI
 * functions. The model and its equations are in nmsid_model.c.
 *
 * The FMU holds N_JOINTS joints' twins side by side (one for a one-joint twin file), each
 * with the variables of a one-joint FMU: value reference vr is joint vr / N_REAL's local
 * reference vr % N_REAL (Integer and Boolean likewise), and the continuous states are the
 * joints' NX states one joint after the other. The joints share only the time. */

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "nmsid_model.h"

/* ---- FMI 2.0 interface -------------------------------------------------------------- */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cat[])
{ (void)n; (void)cat; ((Model *)c)->logging = on; return fmi2OK; }

static void set_defaults(Model *m)
{
    int k;
    for (k = 0; k < N_JOINTS; k++) {
        Joint *J = &m->j[k];
        memcpy(J->r, START_REAL[k], sizeof J->r);
        memcpy(J->i, START_INTEGER[k], sizeof J->i);
        memcpy(J->b, START_BOOLEAN[k], sizeof J->b);
        J->der_rE = J->der_sE = 0.0;
    }
    m->time = 0.0;
}

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String loc,
                              const fmi2CallbackFunctions *cb, fmi2Boolean visible,
                              fmi2Boolean logging)
{
    Model *m;
    (void)loc; (void)visible;
    if (!guid || strcmp(guid, MODEL_GUID) != 0) {
        if (cb && cb->logger)
            cb->logger(cb->componentEnvironment, name, fmi2Error, "logStatusError",
                       "GUID %s does not match this binary's %s", guid ? guid : "(null)",
                       MODEL_GUID);
        return NULL;
    }
    m = (Model *)calloc(1, sizeof(Model));
    if (!m) return NULL;
    m->cb = cb;
    m->name = name;
    m->is_cs = type == fmi2CoSimulation;
    m->logging = logging;
    set_defaults(m);
    return m;
}

void fmi2FreeInstance(fmi2Component c) { free(c); }

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tolDef, fmi2Real tol, fmi2Real t0,
                               fmi2Boolean stopDef, fmi2Real tStop)
{ (void)tolDef; (void)tol; (void)stopDef; (void)tStop; ((Model *)c)->time = t0; return fmi2OK; }

fmi2Status fmi2EnterInitializationMode(fmi2Component c) { ((Model *)c)->in_init = 1; return fmi2OK; }

fmi2Status fmi2ExitInitializationMode(fmi2Component c)
{
    /* at rest until rest_lead_s before the start, then a straight line to the first input
       (`nmsid twin simulate` assumes one sampling period) */
    Model *m = (Model *)c;
    int k;
    m->in_init = 0;
    for (k = 0; k < N_JOINTS; k++) {
        Joint *J = &m->j[k];
        double r = J->r[VR_rE], s = J->r[VR_sE], lead = J->r[VR_rest_lead_s], t = m->time;
        double L = J->r[VR_dead_time_s];
        memset(&J->r[VR_x0], 0, sizeof(double) * NX);
        J->h0 = J->hn = 0;
        J->rest_sE = s;
        if (lead > 0.0 && !hist_push(m, J, t - lead, 0.5, s, t, r, s)) return fmi2Error;
        if (!m->is_cs) { if (!hist_push(m, J, t, r, s, t, r, s)) return fmi2Error; }
        if (lead > 0.0 && !advance_delayed(m, J, t - lead - L, t - L)) return fmi2Error;
        J->last_rE = r;
        J->last_sE = s;
        outputs(J);
    }
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) { (void)c; return fmi2OK; }
fmi2Status fmi2Reset(fmi2Component c) { set_defaults((Model *)c); return fmi2OK; }

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[])
{
    Model *m = (Model *)c;
    size_t k;
    int j;
    for (j = 0; j < N_JOINTS; j++) outputs(&m->j[j]);
    for (k = 0; k < n; k++) {
        Joint *J;
        fmi2ValueReference u;
        if (vr[k] >= N_REAL * N_JOINTS) return fmi2Error;
        J = &m->j[vr[k] / N_REAL];
        u = vr[k] % N_REAL;
        if (u >= VR_dx0 && u < VR_dx0 + NX) {
            double dx[NX];
            derivatives(J, m->time, dx);
            v[k] = dx[u - VR_dx0];
        } else v[k] = J->r[u];
    }
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[])
{
    size_t k;
    for (k = 0; k < n; k++) {
        if (vr[k] >= N_INTEGER * N_JOINTS) return fmi2Error;
        v[k] = ((Model *)c)->j[vr[k] / N_INTEGER].i[vr[k] % N_INTEGER];
    }
    return fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[])
{
    size_t k;
    for (k = 0; k < n; k++) {
        if (vr[k] >= N_BOOLEAN * N_JOINTS) return fmi2Error;
        v[k] = ((Model *)c)->j[vr[k] / N_BOOLEAN].b[vr[k] % N_BOOLEAN];
    }
    return fmi2OK;
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[])
{ (void)c; (void)vr; (void)v; return n ? fmi2Error : fmi2OK; }

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real v[])
{
    Model *m = (Model *)c;
    size_t k;
    int j;
    for (k = 0; k < n; k++) {
        Joint *J;
        fmi2ValueReference u;
        if (vr[k] >= N_REAL * N_JOINTS) return fmi2Error;
        if (!isfinite(v[k])) {
            logmsg(m, fmi2Error, "logStatusError", "value reference %u set to a non-finite "
                   "value", (unsigned)vr[k]);
            return fmi2Error;
        }
        J = &m->j[vr[k] / N_REAL];
        u = vr[k] % N_REAL;
        J->r[u] = v[k];
        if (u == VR_rE) J->der_rE = 0.0;
        if (u == VR_sE) J->der_sE = 0.0;
    }
    for (j = 0; j < N_JOINTS; j++) {
        Joint *J = &m->j[j];
        if (!m->is_cs && !m->in_init && J->hn > 0 && J->r[VR_dead_time_s] > 0.0) {
            /* model exchange: the history joins the values set at successive times by
               straight lines */
            double *g = hseg(J, J->hn - 1);
            if (m->time > g[3]) {
                if (!hist_push(m, J, g[3], g[4], g[5], m->time, J->r[VR_rE], J->r[VR_sE]))
                    return fmi2Error;
                hist_prune(J, m->time - J->r[VR_dead_time_s]);
            } else { g[4] = J->r[VR_rE]; g[5] = J->r[VR_sE]; }
        }
    }
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[])
{
    size_t k;
    for (k = 0; k < n; k++) {
        if (vr[k] >= N_INTEGER * N_JOINTS) return fmi2Error;
        ((Model *)c)->j[vr[k] / N_INTEGER].i[vr[k] % N_INTEGER] = v[k];
    }
    return fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[])
{
    size_t k;
    for (k = 0; k < n; k++) {
        if (vr[k] >= N_BOOLEAN * N_JOINTS) return fmi2Error;
        ((Model *)c)->j[vr[k] / N_BOOLEAN].b[vr[k] % N_BOOLEAN] = v[k];
    }
    return fmi2OK;
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String v[])
{ (void)c; (void)vr; (void)v; return n ? fmi2Error : fmi2OK; }

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s)
{
    Model *copy = (Model *)malloc(sizeof(Model));
    if (!copy) return fmi2Error;
    memcpy(copy, c, sizeof(Model));
    *s = copy;
    return fmi2OK;
}
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s)
{ memcpy(c, s, sizeof(Model)); return fmi2OK; }
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s)
{ (void)c; free(*s); *s = NULL; return fmi2OK; }
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *size)
{ (void)c; (void)s; *size = sizeof(Model); return fmi2OK; }
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t size)
{ (void)c; if (size < sizeof(Model)) return fmi2Error; memcpy(b, s, sizeof(Model)); return fmi2OK; }
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t size, fmi2FMUstate *s)
{
    Model *copy;
    if (size < sizeof(Model)) return fmi2Error;
    copy = (Model *)malloc(sizeof(Model));
    if (!copy) return fmi2Error;
    memcpy(copy, b, sizeof(Model));
    copy->cb = ((Model *)c)->cb;
    copy->name = ((Model *)c)->name;
    *s = copy;
    return fmi2OK;
}
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference z[], size_t nz,
                                        const fmi2Real dv[], fmi2Real dz[])
{ (void)c; (void)u; (void)nu; (void)z; (void)nz; (void)dv; (void)dz; return fmi2Error; }

/* ---- model exchange ---- */
fmi2Status fmi2EnterEventMode(fmi2Component c) { (void)c; return fmi2OK; }
fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *ev)
{
    (void)c;
    ev->newDiscreteStatesNeeded = fmi2False;
    ev->terminateSimulation = fmi2False;
    ev->nominalsOfContinuousStatesChanged = fmi2False;
    ev->valuesOfContinuousStatesChanged = fmi2False;
    ev->nextEventTimeDefined = fmi2False;
    ev->nextEventTime = 0.0;
    return fmi2OK;
}
fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) { (void)c; return fmi2OK; }
/* A step event when the importer has changed an input since the last completed step: an
   importer that sets inputs only between its steps (FMPy) then restarts its solver there
   instead of carrying a step integrated with the old inputs past the change. */
fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSet, fmi2Boolean *enter,
                                       fmi2Boolean *term)
{
    Model *m = (Model *)c;
    int k;
    (void)noSet;
    *enter = fmi2False;
    for (k = 0; k < N_JOINTS; k++) {
        Joint *J = &m->j[k];
        if (J->r[VR_rE] != J->last_rE || J->r[VR_sE] != J->last_sE) *enter = fmi2True;
        J->last_rE = J->r[VR_rE];
        J->last_sE = J->r[VR_sE];
    }
    *term = fmi2False;
    return fmi2OK;
}
fmi2Status fmi2SetTime(fmi2Component c, fmi2Real t) { ((Model *)c)->time = t; return fmi2OK; }
fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t n)
{
    int k;
    if (n != NX * N_JOINTS) return fmi2Error;
    for (k = 0; k < N_JOINTS; k++)
        memcpy(&((Model *)c)->j[k].r[VR_x0], x + k * NX, sizeof(double) * NX);
    return fmi2OK;
}
fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real dx[], size_t n)
{
    Model *m = (Model *)c;
    int k;
    if (n != NX * N_JOINTS) return fmi2Error;
    for (k = 0; k < N_JOINTS; k++) {
        Joint *J = &m->j[k];
        if (!params_ok(m, J, J->r[VR_sE])) return fmi2Error;
        derivatives(J, m->time, dx + k * NX);
    }
    return fmi2OK;
}
fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real e[], size_t n)
{ (void)c; (void)e; return n ? fmi2Error : fmi2OK; }
fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t n)
{
    int k;
    if (n != NX * N_JOINTS) return fmi2Error;
    for (k = 0; k < N_JOINTS; k++)
        memcpy(x + k * NX, &((Model *)c)->j[k].r[VR_x0], sizeof(double) * NX);
    return fmi2OK;
}
fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x[], size_t n)
{ size_t k; (void)c; for (k = 0; k < n; k++) x[k] = 1.0; return fmi2OK; }

/* ---- co-simulation ---- */
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                       const fmi2Integer order[], const fmi2Real v[])
{
    Model *m = (Model *)c;
    size_t k;
    for (k = 0; k < n; k++) {
        Joint *J;
        fmi2ValueReference u;
        if (order[k] != 1) continue;               /* the model is exact for straight lines */
        if (vr[k] >= N_REAL * N_JOINTS) return fmi2Error;
        J = &m->j[vr[k] / N_REAL];
        u = vr[k] % N_REAL;
        if (u == VR_rE) J->der_rE = v[k];
        else if (u == VR_sE) J->der_sE = v[k];
        else return fmi2Error;
    }
    return fmi2OK;
}
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                        const fmi2Integer order[], fmi2Real v[])
{ size_t k; (void)c; (void)vr; (void)order; for (k = 0; k < n; k++) v[k] = 0.0; return fmi2Error; }

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior)
{
    Model *m = (Model *)c;
    int k;
    if (!(h >= 0.0)) return fmi2Error;
    for (k = 0; k < N_JOINTS; k++) {
        Joint *J = &m->j[k];
        double r0 = J->r[VR_rE], s0 = J->r[VR_sE];
        double r1 = r0 + J->der_rE * h, s1 = s0 + J->der_sE * h;
        double L = J->r[VR_dead_time_s];
        if (!hist_push(m, J, t, r0, s0, t + h, r1, s1)) return fmi2Error;
        if (!advance_delayed(m, J, t - L, t + h - L)) return fmi2Error;
        hist_prune(J, t + h - L);
        if (s0 > 0.0) J->r[VR_x0 + 6] += h;    /* cumulative stimulation (fatigue) */
        /* the inputs the model sees at the new time are the extrapolated lines' ends */
        J->r[VR_rE] = r1;
        J->r[VR_sE] = s1;
        J->der_rE = J->der_sE = 0.0;
    }
    (void)noSetPrior;
    m->time = t + h;
    return fmi2OK;
}
fmi2Status fmi2CancelStep(fmi2Component c) { (void)c; return fmi2Error; }
fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *v)
{ (void)c; (void)s; *v = fmi2OK; return fmi2Discard; }
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *v)
{ Model *m = (Model *)c; if (s == fmi2LastSuccessfulTime) { *v = m->time; return fmi2OK; } return fmi2Discard; }
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *v)
{ (void)c; (void)s; (void)v; return fmi2Discard; }
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *v)
{ (void)c; (void)s; *v = fmi2False; return fmi2Discard; }
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *v)
{ (void)c; (void)s; (void)v; return fmi2Discard; }
