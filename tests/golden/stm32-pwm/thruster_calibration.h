/*
 * rigtool VERSION: thruster calibration, depth 0.3 m. Generated: make it again with rigtool export-cal rather than edit it.
 * source run, run name, thruster, creation time, command unit: RIGTOOL_SOURCE_RUN, RIGTOOL_RUN_NAME, RIGTOOL_THRUSTER_ID, RIGTOOL_CREATED_UTC, RIGTOOL_COMMAND_UNIT.
 * units: thrust N, command in the command unit, speed r/min (docs/artefacts.md).
 */

#ifndef RIGTOOL_THRUSTER_CALIBRATION_H
#define RIGTOOL_THRUSTER_CALIBRATION_H

#include <math.h>

#define RIGTOOL_SOURCE_RUN "RUN-ID"
#define RIGTOOL_RUN_NAME "stm32-pwm"
#define RIGTOOL_THRUSTER_ID "stern-1"
#define RIGTOOL_CREATED_UTC "TIME"
#define RIGTOOL_COMMAND_UNIT "pwm_counts"
#define RIGTOOL_NEUTRAL_COMMAND 0.0
#define RIGTOOL_C_P_FWD NAN /* N/(r/min)^2: f = C_p |n| n, n > 0 */
#define RIGTOOL_C_P_REV NAN /* N/(r/min)^2: n < 0 */
#define RIGTOOL_N_DEAD_ZONES 2
static const double rigtool_dead_zones[] = {0.0, 206.0, 428.0, 445.0}; /* command pairs lo, hi; one NAN when there are none */
#define RIGTOOL_N_BRANCHES 2
static const int rigtool_branch_start[] = {0, 40, 69};
static const int rigtool_branch_sign[] = {1, -1}; /* +1 forward, -1 reverse */
#define RIGTOOL_BRANCH_DIRECTIONS "forward, reverse" /* in branch order */
static const double rigtool_lut_thrust[] = {0.150495657, 0.306430221, 0.463035492, 0.6189284, 0.774581854, 0.931812127, 1.08872585, 1.2445956, 1.40083711, 1.55648165, 1.71290219, 1.87042866, 2.02730622, 2.18424071, 2.33899979, 2.4960568, 2.65319236, 2.80759957, 2.96547865, 3.12317446, 3.27828369, 3.43443735, 3.59119102, 3.74812548, 3.90494944, 4.06098821, 4.21729214, 4.37437793, 4.53127036, 4.6878498, 4.84246725, 4.99858143, 4.99898596, 4.99901048, 4.99914023, 4.99914416, 4.99931267, 4.99935847, 4.99995024, 5.00032173, -2.99978946, -2.99978407, -2.999627, -2.99953965, -2.99887097, -2.88325061, -2.76888912, -2.65302399, -2.53659289, -2.42124542, -2.30428873, -2.18862068, -2.07242895, -1.9569332, -1.84217808, -1.72570249, -1.61024988, -1.49361208, -1.37873689, -1.26173423, -1.14702837, -1.03146125, -0.914938479, -0.800523248, -0.150181635, -0.132226841, -0.115062653, -0.0967517699, -0.0801514373}; /* N, ascending per branch */
static const double rigtool_lut_command[] = {427.0, 426.0, 425.0, 424.0, 423.0, 422.0, 421.0, 420.0, 419.0, 418.0, 417.0, 416.0, 415.0, 414.0, 413.0, 412.0, 411.0, 410.0, 409.0, 408.0, 407.0, 406.0, 405.0, 404.0, 403.0, 402.0, 401.0, 400.0, 399.0, 398.0, 397.0, 396.0, 378.0, 375.0, 289.0, 277.0, 276.0, 256.0, 218.0, 208.0, 797.0, 787.0, 676.0, 471.0, 470.0, 469.0, 468.0, 467.0, 466.0, 465.0, 464.0, 463.0, 462.0, 461.0, 460.0, 459.0, 458.0, 457.0, 456.0, 455.0, 454.0, 453.0, 452.0, 451.0, 450.0, 449.0, 448.0, 447.0, 446.0};

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
static const double rigtool_test_thrust[] = {0.150495657, 0.7567239161249999, 1.3629521752499998, 1.9691804343749997, 2.5754086934999996, 3.1816369526249995, 3.7878652117499994, 4.394093470874999, 5.00032173, -2.99978946, -2.6348347071625002, -2.269879954325, -1.9049252014875, -1.53997044865, -1.1750156958125002, -0.8100609429749999, -0.44510619013749997, -0.0801514373, 0.0, 0.0752478285, 7.500482594999999, -0.04007571865, -4.49968419};
static const double rigtool_test_command[] = {427.0, 423.11472882493825, 419.2424767576171, 415.3705168898917, 411.4950099550986, 407.62308824158947, 403.7465965548249, 399.8743372075058, 208.0, 797.0, 466.8437764236746, 463.70252134729515, 460.54679147638467, 457.39745578748915, 454.2439921187331, 451.0833603611306, 450.4534917484013, 446.0, 0.0, 0.0, 208.0, 0.0, 797.0};
static const int rigtool_test_status[] = {0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 2, 1, 2, 1};

#endif /* RIGTOOL_THRUSTER_CALIBRATION_H */
