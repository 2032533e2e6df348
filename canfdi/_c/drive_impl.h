/* The drive loop's parts (drive.c, drive_init.c, announce.c, diagnose.c, decisions.c,
 * compensate.c): private to them. */
#ifndef CFDI_DRIVE_IMPL_H
#define CFDI_DRIVE_IMPL_H

#include "drive.h"

/* A sample's width: p inputs and q outputs. */
#define CFDI_WIDTH(t) ((t)->p + (t)->q)

/* A fault's estimates as the diagnosis found them, before they are folded in: an actuator's
 * eta and lambda (a bias alone: eta 1, fixed), a sensor's bias, with the variances the event
 * reports (an actuator's eta and lambda, a sensor's bias in var[0]). */
typedef struct {
    int32_t channel;              /* an input j (j), an output j (p + j) */
    int64_t onset;
    cfdi_real eta, lam, bias;
    cfdi_real var[2];
    int has_var[2];
    int fixed_eta;
    int correction;               /* what an earlier estimate left (a leftover, a tracker's) */
} cfdi_found;

/* compensate.c: the compensation (canfdi.core.records) */
int cfdi_is_actuator(const cfdi_drive *d, int32_t channel);
void cfdi_comp_reset(cfdi_drive *d);
void cfdi_comp_row(const cfdi_drive *d, int64_t k, const cfdi_real *raw, cfdi_real *out);
int cfdi_comp_fold(cfdi_drive *d, const cfdi_found *f, cfdi_event *ev);

/* drive.c: the samples kept, the history; announce.c: the frames and events queued */
const cfdi_real *cfdi_rec_row(const cfdi_drive *d, int64_t k);
int cfdi_rec_offered(const cfdi_drive *d, int64_t k);
int cfdi_rec_window(cfdi_drive *d, int64_t k, cfdi_real *rn);
int cfdi_rec_seen(cfdi_drive *d, int64_t k, cfdi_real *rn);
void cfdi_reload_window(cfdi_drive *d, int64_t k);
void cfdi_announce(cfdi_drive *d, const cfdi_event *ev);
void cfdi_restart_detector(cfdi_drive *d, int64_t k);

/* diagnose.c: an alarm's diagnosis */
int cfdi_diag_start(cfdi_drive *d, int64_t k, int64_t t_ns, int64_t change_point);
int cfdi_diag_sample(cfdi_drive *d, int64_t k, int64_t t_ns);
int cfdi_diag_catch_up(cfdi_drive *d, size_t share, int64_t upto);
cfdi_signatures cfdi_diag_signatures(const cfdi_drive *d);
int32_t cfdi_diag_channel(const cfdi_drive *d, size_t hyp);
cfdi_real *cfdi_fit_h(const cfdi_drive *d);
cfdi_real *cfdi_fit_cost(const cfdi_drive *d);
int cfdi_solve_fit(cfdi_drive *d, size_t hyp, size_t kb, cfdi_real *theta, cfdi_real *P);
int cfdi_reported(cfdi_drive *d, size_t hyp, size_t kb, cfdi_real *var);

/* decisions.c: what a decision makes, a tracker's checkpoint */
int cfdi_name_fault(cfdi_drive *d, const cfdi_decision *dec, int64_t k, int64_t t_ns);
int cfdi_accept_fault(cfdi_drive *d, const cfdi_decision *dec, int64_t k, int64_t t_ns);
int cfdi_unexplained(cfdi_drive *d, int64_t k, int64_t t_ns);
int cfdi_diag_refine(cfdi_drive *d, int64_t k, int64_t t_ns);

#endif
