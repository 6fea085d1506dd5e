/* The bench rig's timer and watchdog (protocols/rigs/stm32-bench.yaml), shared by every build.
 *
 * These must agree with the rig file's actuator section:
 *   timer_clock_hz -> BRIDGE_TIMER_CLOCK_HZ, psc -> BRIDGE_PSC, arr -> BRIDGE_ARR,
 *   neutral (counts) -> BRIDGE_NEUTRAL_CCR, watchdog_ms -> BRIDGE_WATCHDOG_MS.
 *
 *   tick  = (PSC + 1) / f_TIM
 *   f_PWM = f_TIM / ((PSC + 1)(ARR + 1))     72 MHz / (1 * 800) = 90 kHz
 *   duty  = CCR / (ARR + 1)
 *
 * An ESC at 50 Hz with 1 us ticks: PSC 71, ARR 19999, neutral 1500 (72 MHz / (72 * 20000)).
 * Override any of them with -D on the compiler command line. */
#ifndef BRIDGE_RIG_H
#define BRIDGE_RIG_H

#ifndef BRIDGE_TIMER_CLOCK_HZ
#define BRIDGE_TIMER_CLOCK_HZ 72000000u
#endif
#ifndef BRIDGE_PSC
#define BRIDGE_PSC 0u
#endif
#ifndef BRIDGE_ARR
#define BRIDGE_ARR 799u
#endif
#ifndef BRIDGE_NEUTRAL_CCR
#define BRIDGE_NEUTRAL_CCR 0u
#endif
#ifndef BRIDGE_WATCHDOG_MS
#define BRIDGE_WATCHDOG_MS 500u
#endif
#ifndef BRIDGE_TELEMETRY_MS
#define BRIDGE_TELEMETRY_MS 0u  /* 0 = no TEL lines */
#endif
#ifndef BRIDGE_CHANNELS
#define BRIDGE_CHANNELS 4u
#endif
/* The compare values the output can put out (a timer: all of 0..ARR). */
#ifndef BRIDGE_CCR_MIN
#define BRIDGE_CCR_MIN 0u
#endif
#ifndef BRIDGE_CCR_MAX
#define BRIDGE_CCR_MAX BRIDGE_ARR
#endif

#endif
