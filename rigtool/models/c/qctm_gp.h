/* Reference C evaluator of an exported QCTM-GP thrust model (qctm_gp.json, format 2-7).
 *
 * C99, libc and libm only. It computes what rigtool.models.ThrustModel.evaluate computes
 * (rigtool/models/qctm.py is the reference; docs/cavitation.md, "Export", the recipe).
 *
 * Build the command-line program (reads CSV block means on stdin, see qctm_eval_main.c):
 *     cc -std=c99 -O2 -o qctm_eval qctm_gp.c qctm_eval_main.c -lm
 */
#ifndef QCTM_GP_H
#define QCTM_GP_H

#include <stddef.h>

/* Per-block flags (a bit field; the same values as rigtool.models.domain) */
#define QCTM_OUT_OF_DOMAIN 1 /* an input outside the training ranges or far from every row */
#define QCTM_CURRENT_FAULT 2 /* shortfall outside bounds.shortfall: the speed estimate */
#define QCTM_CLAMPED 4       /* thrust held to [0, f_BETM + above_n] in the speed's direction */

#define QCTM_Z95 1.959963984540054 /* two-sided 95 % normal quantile, rigtool.models.Z95 */

typedef struct qctm_model qctm_model;

/* Load a model. `path` is the calibration folder holding qctm_gp.json, or the .json file
 * itself (any path ending in ".json"). The posterior-variance matrix gp.variance_file
 * (default qctm_gp_kinv.npy, next to the .json) is read when it exists; without it the
 * prior variance is used, as in Python. Format 6 says which it is: gp.signal true needs the
 * file, false (no GP signal: no mean or posterior terms) refuses one. Returns NULL with a
 * message in err on failure. */
qctm_model *qctm_load(const char *path, char *err, size_t errlen);

/* 1 when the posterior-variance matrix was loaded, 0 when the prior variance is used (or
 * the model has no GP signal). */
int qctm_has_kinv(const qctm_model *m);

/* 1 when the model was trained on two runs or more, so its 95 % intervals were checked run
 * by run; 0 when trained on one run (checked only on held-out blocks of that run: they hold
 * on a new run only as far as it resembles that one); -1 when the file does not say. */
int qctm_intervals_validated(const qctm_model *m);

void qctm_free(qctm_model *m);

/* Evaluate `count` consecutive block means. segment: one label per block (a new segment
 * starts where the label changes), or NULL for one continuous record. distance may be NULL.
 * Non-finite speed or depth give NaN outputs, a NaN current is a current fault.
 * Returns 0, or -1 (message in err) when memory runs out. */
int qctm_evaluate(const qctm_model *m, size_t count, const double *speed_rpm,
                  const double *current_a, const double *depth_m, const long *segment,
                  double *thrust_n, double *lo95, double *hi95, int *flags, double *distance,
                  char *err, size_t errlen);

#endif
