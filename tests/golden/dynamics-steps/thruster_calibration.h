/*
 * rigtool VERSION: thruster calibration, depth 1 m. Generated: make it again with rigtool export-cal rather than edit it.
 * source run, run name, thruster, creation time, command unit: RIGTOOL_SOURCE_RUN, RIGTOOL_RUN_NAME, RIGTOOL_THRUSTER_ID, RIGTOOL_CREATED_UTC, RIGTOOL_COMMAND_UNIT.
 * units: thrust N, command in the command unit, speed r/min (docs/artefacts.md).
 */

#ifndef RIGTOOL_THRUSTER_CALIBRATION_H
#define RIGTOOL_THRUSTER_CALIBRATION_H

#include <math.h>

#define RIGTOOL_SOURCE_RUN "RUN-ID"
#define RIGTOOL_RUN_NAME "dynamics-steps"
#define RIGTOOL_THRUSTER_ID "T1"
#define RIGTOOL_CREATED_UTC "TIME"
#define RIGTOOL_COMMAND_UNIT "percent"
#define RIGTOOL_NEUTRAL_COMMAND 0.0
#define RIGTOOL_C_P_FWD 1.9317781531674346e-05 /* N/(r/min)^2: f = C_p |n| n, n > 0 */
#define RIGTOOL_C_P_REV 1.548384125528356e-05 /* N/(r/min)^2: n < 0 */
#define RIGTOOL_N_DEAD_ZONES 1
static const double rigtool_dead_zones[] = {0.0, 0.0}; /* command pairs lo, hi; one NAN when there are none */
#define RIGTOOL_N_BRANCHES 2
static const int rigtool_branch_start[] = {0, 3, 6};
static const int rigtool_branch_sign[] = {-1, 1}; /* +1 forward, -1 reverse */
#define RIGTOOL_BRANCH_DIRECTIONS "reverse, forward" /* in branch order */
static const double rigtool_lut_thrust[] = {-41.9268863, -18.1398727, -4.50431827, 5.63635995, 22.683877, 52.3870914}; /* N, ascending per branch */
static const double rigtool_lut_command[] = {-90.0, -60.0, -30.0, 30.0, 60.0, 90.0};

/* Dynamics, speed s follows its steady value (s|s| = the steady thrust) with RIGTOOL_TAU_N_S; the inflow m follows s with RIGTOOL_TAU_A_S; thrust = s|s| + RIGTOOL_INFLOW_GAIN (s|s| - m|m|); a command acts RIGTOOL_DELAY_S after it is sent (docs/dynamics.md); for consumers with a simpler model, whatever the model above: a first-order lag of s with RIGTOOL_TAU_FIRST_ORDER_S alone; the same with RIGTOOL_TAU_RISE_S while |s| grows and RIGTOOL_TAU_FALL_S while it shrinks; Yoerger's n' = beta f_cmd - RIGTOOL_YOERGER_ALPHA n|n| (beta: RIGTOOL_YOERGER_BETA_FWD for f_cmd >= 0, else RIGTOOL_YOERGER_BETA_REV) with thrust (RIGTOOL_YOERGER_ALPHA / beta) n|n|, beta by the sign of n, n in RIGTOOL_YOERGER_STATE_UNIT (each with RIGTOOL_DELAY_S); RIGTOOL_FIRST_ORDER_ERROR_FRAC, RIGTOOL_RISE_FALL_ERROR_FRAC, RIGTOOL_YOERGER_ERROR_FRAC: each one's RMS deviation from the model above over the step run, as a fraction of full scale (adequate up to 0.02; NaN: not fitted). Seconds. */
#define RIGTOOL_HAS_DYNAMICS 1
#define RIGTOOL_DYNAMICS_RUN "RUN-ID"
#define RIGTOOL_DYNAMICS_MODEL "two-state"
#define RIGTOOL_TAU_N_S 0.2999116868426909
#define RIGTOOL_TAU_A_S 0.6024663903760878 /* NAN: one-state */
#define RIGTOOL_INFLOW_GAIN 0.3487602375473379
#define RIGTOOL_DELAY_S 7.014825116742968e-05
#define RIGTOOL_DYNAMICS_REVERSE_RATIO NAN /* C_p_rev / C_p_fwd seen in steps through zero; NAN: none */
#define RIGTOOL_YOERGER_STATE_UNIT "r/min"
#define RIGTOOL_YOERGER_ALPHA 0.0025901773109160966
#define RIGTOOL_YOERGER_BETA_FWD 134.08254496869216
#define RIGTOOL_YOERGER_BETA_REV 167.28260566687538
#define RIGTOOL_TAU_FIRST_ORDER_S 0.20195618845225155 /* the best single lag */
#define RIGTOOL_TAU_RISE_S 0.20686906402136185 /* NAN: not fitted */
#define RIGTOOL_TAU_FALL_S 0.14288941951167858
#define RIGTOOL_FIRST_ORDER_ERROR_FRAC 0.02519091354942151 /* deviations from the selected model, fraction of full scale */
#define RIGTOOL_RISE_FALL_ERROR_FRAC 0.02550584175330403
#define RIGTOOL_YOERGER_ERROR_FRAC 0.039796060915783776

#define RIGTOOL_CMD_OK 0
#define RIGTOOL_CMD_CLAMPED 1
#define RIGTOOL_CMD_BELOW_MIN 2
#define RIGTOOL_CMD_NAN 3
#define RIGTOOL_CMD_GAP 4

/* The command giving thrust_n (N), and in *status why (RIGTOOL_CMD_*): the neutral command
   for 0 N; linear interpolation in the first branch whose thrust range holds thrust_n; beyond
   the largest thrust measured in that direction, that direction's extreme command (CLAMPED);
   between 0 and the smallest thrust the thruster makes outside its dead band, the neutral
   command (BELOW_MIN); between two branches, the nearer branch end (GAP); NAN for NAN. */
static inline double rigtool_command_for_thrust_status(double thrust_n, int *status)
{
    double sign, near_gap = INFINITY, near_cmd, min_mag = INFINITY, max_mag = -1.0, max_cmd;
    *status = RIGTOOL_CMD_OK;
    if (thrust_n != thrust_n) { *status = RIGTOOL_CMD_NAN; return NAN; }
    if (thrust_n == 0.0) return RIGTOOL_NEUTRAL_COMMAND;
    sign = thrust_n > 0.0 ? 1.0 : -1.0;
    near_cmd = max_cmd = RIGTOOL_NEUTRAL_COMMAND;
    for (int b = 0; b < RIGTOOL_N_BRANCHES; ++b) {
        int lo = rigtool_branch_start[b], hi = rigtool_branch_start[b + 1] - 1;
        if (thrust_n >= rigtool_lut_thrust[lo] && thrust_n <= rigtool_lut_thrust[hi]) {
            while (hi - lo > 1) {
                int mid = (lo + hi) / 2;
                if (rigtool_lut_thrust[mid] <= thrust_n) lo = mid; else hi = mid;
            }
            if (hi == lo || rigtool_lut_thrust[hi] == rigtool_lut_thrust[lo])
                return rigtool_lut_command[lo];
            return rigtool_lut_command[lo] + (thrust_n - rigtool_lut_thrust[lo])
                   / (rigtool_lut_thrust[hi] - rigtool_lut_thrust[lo])
                   * (rigtool_lut_command[hi] - rigtool_lut_command[lo]);
        }
    }
    for (int b = 0; b < RIGTOOL_N_BRANCHES; ++b) {
        int ends[2];
        if (rigtool_branch_sign[b] != (int)sign) continue;
        ends[0] = rigtool_branch_start[b];
        ends[1] = rigtool_branch_start[b + 1] - 1;
        for (int e = 0; e < 2; ++e) {
            double m = sign * rigtool_lut_thrust[ends[e]];
            double gap = fabs(rigtool_lut_thrust[ends[e]] - thrust_n);
            if (gap < near_gap) { near_gap = gap; near_cmd = rigtool_lut_command[ends[e]]; }
            if (m < min_mag) min_mag = m;
            if (m > max_mag) { max_mag = m; max_cmd = rigtool_lut_command[ends[e]]; }
        }
    }
    if (max_mag < 0.0) { *status = RIGTOOL_CMD_CLAMPED; return RIGTOOL_NEUTRAL_COMMAND; }
    if (sign * thrust_n < min_mag) { *status = RIGTOOL_CMD_BELOW_MIN; return RIGTOOL_NEUTRAL_COMMAND; }
    if (sign * thrust_n > max_mag) { *status = RIGTOOL_CMD_CLAMPED; return max_cmd; }
    *status = RIGTOOL_CMD_GAP;
    return near_cmd;
}

/* The same command without the status. */
static inline double rigtool_command_for_thrust(double thrust_n)
{
    int status;
    return rigtool_command_for_thrust_status(thrust_n, &status);
}

/* The older answer, for those who want it: NAN unless the status is RIGTOOL_CMD_OK. */
static inline double rigtool_command_for_thrust_strict(double thrust_n)
{
    int status;
    double command = rigtool_command_for_thrust_status(thrust_n, &status);
    return status == RIGTOOL_CMD_OK ? command : NAN;
}

/* Test vector: rigtool_command_for_thrust_status(rigtool_test_thrust[i], &s) gives
   rigtool_test_command[i] with s == rigtool_test_status[i]. */
#define RIGTOOL_N_TEST 23
static const double rigtool_test_thrust[] = {-41.9268863, -37.24906529625, -32.5712442925, -27.89342328875, -23.215602285, -18.53778128125, -13.8599602775, -9.182139273749996, -4.50431827, 5.63635995, 11.480201381250001, 17.3240428125, 23.167884243750002, 29.011725675, 34.85556710625, 40.699408537500005, 46.543249968750004, 52.3870914, 0.0, 2.818179975, 78.5806371, -2.252159135, -62.890329449999996};
static const double rigtool_test_command[] = {-90.0, -84.10036785313395, -78.20073570626789, -72.30110355940184, -66.40147141253578, -60.50183926566973, -50.58363388638536, -40.29181694319267, -30.0, 30.0, 40.28391656235358, 50.56783312470716, 60.48884329880809, 66.39107463904648, 72.29330597928485, 78.19553731952324, 84.09776865976161, 90.0, 0.0, 0.0, 90.0, 0.0, -90.0};
static const int rigtool_test_status[] = {0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 2, 1, 2, 1};

#endif /* RIGTOOL_THRUSTER_CALIBRATION_H */
