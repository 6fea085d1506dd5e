/*
 * rigtool VERSION: thruster calibration, depth 1 m. Generated: make it again with rigtool export-cal rather than edit it.
 * source run, run name, thruster, creation time, command unit: RIGTOOL_SOURCE_RUN, RIGTOOL_RUN_NAME, RIGTOOL_THRUSTER_ID, RIGTOOL_CREATED_UTC, RIGTOOL_COMMAND_UNIT.
 * units: thrust N, command in the command unit, speed r/min (docs/artefacts.md). C_p |n| n misses the thrust law chosen on held-out points by up to 0.0 % forward, 0.0 % reverse of full-scale thrust from 10 to 100 % speed (calibration.json thrust_law).
 */

#ifndef RIGTOOL_THRUSTER_CALIBRATION_H
#define RIGTOOL_THRUSTER_CALIBRATION_H

#include <math.h>

#define RIGTOOL_SOURCE_RUN "RUN-ID"
#define RIGTOOL_RUN_NAME "esc-1100-1900"
#define RIGTOOL_THRUSTER_ID "esc-thruster"
#define RIGTOOL_CREATED_UTC "TIME"
#define RIGTOOL_COMMAND_UNIT "pulse_us"
#define RIGTOOL_NEUTRAL_COMMAND 1500.0
#define RIGTOOL_C_P_FWD 3.462260050260254e-06 /* N/(r/min)^2: f = C_p |n| n, n > 0 */
#define RIGTOOL_C_P_REV 2.769790702511574e-06 /* N/(r/min)^2: n < 0 */
#define RIGTOOL_N_DEAD_ZONES 1
static const double rigtool_dead_zones[] = {1476.0, 1524.0}; /* command pairs lo, hi; one NAN when there are none */
#define RIGTOOL_N_BRANCHES 2
static const int rigtool_branch_start[] = {0, 94, 188};
static const int rigtool_branch_sign[] = {-1, 1}; /* +1 forward, -1 reverse */
#define RIGTOOL_BRANCH_DIRECTIONS "reverse, forward" /* in branch order */
static const double rigtool_lut_thrust[] = {-40.0063625, -39.1342057, -38.3119764, -37.4706236, -36.6313402, -35.8412017, -35.028217, -34.2294232, -33.4737371, -32.6766725, -31.9217859, -31.1596084, -30.4237639, -29.6617457, -28.9462951, -28.2240365, -27.5207817, -26.8072564, -26.1153812, -25.4255363, -24.7479945, -24.0897473, -23.4338787, -22.7927788, -22.1453845, -21.50829, -20.8792509, -20.2812001, -19.6700653, -19.0809029, -18.4943733, -17.9180863, -17.351296, -16.7991123, -16.2386393, -15.6997037, -15.1711868, -14.6509952, -14.1458531, -13.6397629, -13.143615, -12.6587879, -12.1779307, -11.7255595, -11.2714283, -10.8107052, -10.3747902, -9.9469947, -9.52951529, -9.11578641, -8.70969927, -8.32104157, -7.93196277, -7.55995485, -7.19505768, -6.82844183, -6.48732967, -6.14536409, -5.81907332, -5.49635496, -5.18252297, -4.88232866, -4.58668465, -4.30361859, -4.0233643, -3.75843205, -3.50210948, -3.25735683, -3.02133442, -2.78640883, -2.56560573, -2.35512388, -2.15041793, -1.95955854, -1.77263898, -1.60040228, -1.43756849, -1.27573527, -1.13087412, -0.989054688, -0.859107561, -0.736352117, -0.62963433, -0.524349885, -0.433371167, -0.350412443, -0.271757464, -0.208175206, -0.147202759, -0.101046597, -0.0645804636, -0.0338861994, -0.0140780326, -0.0032485374, 0.00598288721, 0.0213472341, 0.0425246543, 0.0804304993, 0.127342722, 0.188810191, 0.258963217, 0.339801707, 0.434853274, 0.540679784, 0.656707292, 0.785642186, 0.921698809, 1.07509845, 1.2364971, 1.41323364, 1.59519456, 1.79277965, 2.00180563, 2.21639377, 2.44992362, 2.68686834, 2.94386961, 3.20960405, 3.47961603, 3.77003101, 4.07344111, 4.38542575, 4.70343058, 5.03420897, 5.38231837, 5.73345102, 6.10270214, 6.47853413, 6.87024484, 7.27329392, 7.68318543, 8.11417536, 8.53902003, 8.9871565, 9.44381717, 9.92182844, 10.3964649, 10.8848138, 11.3863749, 11.9120565, 12.427812, 12.9723838, 13.5259374, 14.0835048, 14.6461761, 15.2305608, 15.8296662, 16.4369669, 17.056298, 17.6793275, 18.3228133, 18.9712335, 19.6344844, 20.3029829, 20.9846999, 21.6864363, 22.3923906, 23.1211892, 23.8509046, 24.5863217, 25.3412357, 26.1166991, 26.8790772, 27.6694561, 28.4776561, 29.2880674, 30.1120525, 30.9407376, 31.7816316, 32.6310456, 33.5165178, 34.4027529, 35.2598204, 36.1773351, 37.0691911, 38.0409759, 38.9745742, 39.8988997, 40.850706, 41.8298803, 42.8026562, 43.7990549, 44.8007944, 45.8068621, 46.8631069, 47.8810583, 48.9560078, 49.9948183}; /* N, ascending per branch */
static const double rigtool_lut_command[] = {1100.0, 1104.0, 1108.0, 1112.0, 1116.0, 1120.0, 1124.0, 1128.0, 1132.0, 1136.0, 1140.0, 1144.0, 1148.0, 1152.0, 1156.0, 1160.0, 1164.0, 1168.0, 1172.0, 1176.0, 1180.0, 1184.0, 1188.0, 1192.0, 1196.0, 1200.0, 1204.0, 1208.0, 1212.0, 1216.0, 1220.0, 1224.0, 1228.0, 1232.0, 1236.0, 1240.0, 1244.0, 1248.0, 1252.0, 1256.0, 1260.0, 1264.0, 1268.0, 1272.0, 1276.0, 1280.0, 1284.0, 1288.0, 1292.0, 1296.0, 1300.0, 1304.0, 1308.0, 1312.0, 1316.0, 1320.0, 1324.0, 1328.0, 1332.0, 1336.0, 1340.0, 1344.0, 1348.0, 1352.0, 1356.0, 1360.0, 1364.0, 1368.0, 1372.0, 1376.0, 1380.0, 1384.0, 1388.0, 1392.0, 1396.0, 1400.0, 1404.0, 1408.0, 1412.0, 1416.0, 1420.0, 1424.0, 1428.0, 1432.0, 1436.0, 1440.0, 1444.0, 1448.0, 1452.0, 1456.0, 1460.0, 1464.0, 1468.0, 1472.0, 1528.0, 1532.0, 1536.0, 1540.0, 1544.0, 1548.0, 1552.0, 1556.0, 1560.0, 1564.0, 1568.0, 1572.0, 1576.0, 1580.0, 1584.0, 1588.0, 1592.0, 1596.0, 1600.0, 1604.0, 1608.0, 1612.0, 1616.0, 1620.0, 1624.0, 1628.0, 1632.0, 1636.0, 1640.0, 1644.0, 1648.0, 1652.0, 1656.0, 1660.0, 1664.0, 1668.0, 1672.0, 1676.0, 1680.0, 1684.0, 1688.0, 1692.0, 1696.0, 1700.0, 1704.0, 1708.0, 1712.0, 1716.0, 1720.0, 1724.0, 1728.0, 1732.0, 1736.0, 1740.0, 1744.0, 1748.0, 1752.0, 1756.0, 1760.0, 1764.0, 1768.0, 1772.0, 1776.0, 1780.0, 1784.0, 1788.0, 1792.0, 1796.0, 1800.0, 1804.0, 1808.0, 1812.0, 1816.0, 1820.0, 1824.0, 1828.0, 1832.0, 1836.0, 1840.0, 1844.0, 1848.0, 1852.0, 1856.0, 1860.0, 1864.0, 1868.0, 1872.0, 1876.0, 1880.0, 1884.0, 1888.0, 1892.0, 1896.0, 1900.0};

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
static const double rigtool_test_thrust[] = {-40.0063625, -35.005973254675, -30.005584009350002, -25.005194764025, -20.0048055187, -15.004416273375, -10.004027028049997, -5.003637782725001, -0.0032485374, 0.00598288721, 6.2545873138087495, 12.503191740407498, 18.751796167006248, 25.000400593604997, 31.249005020203747, 37.4976094468025, 43.74621387340125, 49.9948183, 0.0, 0.002991443605, 74.99222745, -0.0016242687, -60.009543750000006};
static const double rigtool_test_command[] = {1100.0, 1124.1113866698765, 1150.1951176003408, 1178.4815681392647, 1209.809058042841, 1245.2823776979483, 1287.4667327912518, 1342.3835919778094, 1472.0, 1528.0, 1657.6165220401674, 1712.5536808215738, 1754.64632636063, 1790.1940453805598, 1821.4663794495084, 1849.7634288859117, 1875.7878719568832, 1900.0, 1500.0, 1500.0, 1900.0, 1500.0, 1100.0};
static const int rigtool_test_status[] = {0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 2, 1, 2, 1};

#endif /* RIGTOOL_THRUSTER_CALIBRATION_H */
