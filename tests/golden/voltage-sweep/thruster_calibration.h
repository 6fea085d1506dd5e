/*
 * rigtool VERSION: thruster calibration, depth 1 m, supply 16 V. Generated: make it again with rigtool export-cal rather than edit it.
 * source run, run name, thruster, creation time, command unit: RIGTOOL_SOURCE_RUN, RIGTOOL_RUN_NAME, RIGTOOL_THRUSTER_ID, RIGTOOL_CREATED_UTC, RIGTOOL_COMMAND_UNIT.
 * units: thrust N, command in the command unit, speed r/min (docs/artefacts.md). C_p |n| n misses the thrust law chosen on held-out points by up to 0.0 % forward, 0.0 % reverse of full-scale thrust from 10 to 100 % speed (calibration.json thrust_law).
 */

#ifndef RIGTOOL_THRUSTER_CALIBRATION_H
#define RIGTOOL_THRUSTER_CALIBRATION_H

#include <math.h>

#define RIGTOOL_SOURCE_RUN "RUN-ID"
#define RIGTOOL_RUN_NAME "voltage-sweep"
#define RIGTOOL_THRUSTER_ID "esc-thruster"
#define RIGTOOL_CREATED_UTC "TIME"
#define RIGTOOL_COMMAND_UNIT "pulse_us"
#define RIGTOOL_NEUTRAL_COMMAND 1500.0
#define RIGTOOL_C_P_FWD 3.4621082836092885e-06 /* N/(r/min)^2: f = C_p |n| n, n > 0 */
#define RIGTOOL_C_P_REV 2.768848357258459e-06 /* N/(r/min)^2: n < 0 */
#define RIGTOOL_N_DEAD_ZONES 1
static const double rigtool_dead_zones[] = {1475.0, 1525.0}; /* command pairs lo, hi; one NAN when there are none */
#define RIGTOOL_N_BRANCHES 2
static const int rigtool_branch_start[] = {0, 15, 30};
static const int rigtool_branch_sign[] = {-1, 1}; /* +1 forward, -1 reverse */
#define RIGTOOL_BRANCH_DIRECTIONS "reverse, forward" /* in branch order */
static const double rigtool_lut_thrust[] = {-39.9723759, -34.8429912, -30.0272356, -25.5946041, -21.5029478, -17.7644187, -14.3906717, -11.3720953, -8.70640038, -6.3955501, -4.43632351, -2.84276992, -1.59847534, -0.710483643, -0.178686159, 0.223267965, 0.88812561, 1.99929794, 3.55737122, 5.55589073, 8.00220762, 10.8946292, 14.2200802, 17.9995745, 22.2402059, 26.8838955, 31.9831009, 37.5313681, 43.527543, 49.9917773}; /* N, ascending per branch */
static const double rigtool_lut_command[] = {1100.0, 1125.0, 1150.0, 1175.0, 1200.0, 1225.0, 1250.0, 1275.0, 1300.0, 1325.0, 1350.0, 1375.0, 1400.0, 1425.0, 1450.0, 1550.0, 1575.0, 1600.0, 1625.0, 1650.0, 1675.0, 1700.0, 1725.0, 1750.0, 1775.0, 1800.0, 1825.0, 1850.0, 1875.0, 1900.0};

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
static const double rigtool_test_thrust[] = {-39.9723759, -34.998164682375005, -30.02395346475, -25.049742247125003, -20.075531029500002, -15.101319811875001, -10.127108594250004, -5.152897376624999, -0.178686159, 0.223267965, 6.444331631875, 12.665395298750001, 18.886458965625003, 25.107522632500004, 31.328586299375004, 37.54964996625, 43.770713633125006, 49.9917773, 0.0, 0.1116339825, 74.98766595000001, -0.0893430795, -59.958563850000004};
static const double rigtool_test_command[] = {1100.0, 1124.2437032341568, 1150.018511211963, 1178.3291032587158, 1209.545310015776, 1244.733984855155, 1286.676005161067, 1340.8564191824157, 1450.0, 1550.0, 1659.0793726019997, 1713.3122251594596, 1755.2284930118249, 1790.4366300263696, 1821.7910951350136, 1850.0762230361643, 1875.9404463925644, 1900.0, 1500.0, 1500.0, 1900.0, 1500.0, 1100.0};
static const int rigtool_test_status[] = {0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 2, 1, 2, 1};

#endif /* RIGTOOL_THRUSTER_CALIBRATION_H */
