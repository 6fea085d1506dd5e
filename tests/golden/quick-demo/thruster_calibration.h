/*
 * rigtool VERSION: thruster calibration, depth 1 m. Generated: make it again with rigtool export-cal rather than edit it.
 * source run, run name, thruster, creation time, command unit: RIGTOOL_SOURCE_RUN, RIGTOOL_RUN_NAME, RIGTOOL_THRUSTER_ID, RIGTOOL_CREATED_UTC, RIGTOOL_COMMAND_UNIT.
 * units: thrust N, command in the command unit, speed r/min (docs/artefacts.md). C_p |n| n misses the thrust law chosen on held-out points by up to 0.0 % forward, 0.0 % reverse of full-scale thrust from 10 to 100 % speed (calibration.json thrust_law).
 */

#ifndef RIGTOOL_THRUSTER_CALIBRATION_H
#define RIGTOOL_THRUSTER_CALIBRATION_H

#include <math.h>

#define RIGTOOL_SOURCE_RUN "RUN-ID"
#define RIGTOOL_RUN_NAME "quick-demo"
#define RIGTOOL_THRUSTER_ID "demo"
#define RIGTOOL_CREATED_UTC "TIME"
#define RIGTOOL_COMMAND_UNIT "percent"
#define RIGTOOL_NEUTRAL_COMMAND 0.0
#define RIGTOOL_C_P_FWD 1.926406987439977e-05 /* N/(r/min)^2: f = C_p |n| n, n > 0 */
#define RIGTOOL_C_P_REV 1.5406057726400626e-05 /* N/(r/min)^2: n < 0 */
#define RIGTOOL_N_DEAD_ZONES 1
static const double rigtool_dead_zones[] = {0.0, 0.0}; /* command pairs lo, hi; one NAN when there are none */
#define RIGTOOL_N_BRANCHES 2
static const int rigtool_branch_start[] = {0, 10, 20};
static const int rigtool_branch_sign[] = {-1, 1}; /* +1 forward, -1 reverse */
#define RIGTOOL_BRANCH_DIRECTIONS "reverse, forward" /* in branch order */
static const double rigtool_lut_thrust[] = {-49.9209329, -40.4206755, -31.9439591, -24.4556492, -17.9750186, -12.4731587, -7.98558344, -4.49211979, -1.9967728, -0.493910128, 0.621913518, 2.49546051, 5.61818011, 9.97652336, 15.6034756, 22.4655501, 30.5726303, 39.9441563, 50.5448645, 62.382126}; /* N, ascending per branch */
static const double rigtool_lut_command[] = {-100.0, -90.0, -80.0, -70.0, -60.0, -50.0, -40.0, -30.0, -20.0, -10.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0, 90.0, 100.0};

#define RIGTOOL_HAS_DYNAMICS 0 /* no step-response run was given (--dynamics RUN): no time constants */

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
static const double rigtool_test_thrust[] = {-49.9209329, -43.7425550535, -37.564177207, -31.3857993605, -25.207421514, -19.0290436675, -12.850665821, -6.672287974500001, -0.493910128, 0.621913518, 8.34194007825, 16.0619666385, 23.78199319875, 31.502019759, 39.22204631925, 46.9420728795, 54.66209943975, 62.382126, 0.0, 0.310956759, 93.573189, -0.246955064, -74.88139935};
static const double rigtool_test_command[] = {-100.0, -93.49662057945925, -86.63018301166711, -79.25462521322736, -71.00392788765326, -61.62642361917682, -50.68614455449874, -36.24070665369597, -10.0, 10.0, 36.24953064045609, 50.66815223078677, 61.62381901532194, 70.99171624663902, 79.22946382398128, 86.60136704781667, 93.4781988551575, 100.0, 0.0, 0.0, 100.0, 0.0, -100.0};
static const int rigtool_test_status[] = {0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 2, 1, 2, 1};

#endif /* RIGTOOL_THRUSTER_CALIBRATION_H */
